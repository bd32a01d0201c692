#!/bin/sh
# The 3- and 4-action runs of seed 0 started beside the 2-action lanes of run_grid.sh (the same
# commands and folders; resumable), so that every action count has a curve by the deadline.
set -u
OUT=${OUT:-results/ppo/grid}
run() {
    nice -n 10 col ppo --actions "$1" --seed "$2" --episodes 1000 --eval-episodes 100 \
        --config configs/paper.toml --out "$OUT/a$1-s$2" >> "$OUT/a$1-s$2.log" 2>&1
}
run 3 0 & run 4 0 & wait
