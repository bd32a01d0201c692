#!/bin/sh
# Runs stopped before their 1000 (or 200) episodes at the deadline: each one's latest checkpoint
# flown on the 100 held-out starts (checkpoint_eval.json in its folder), all at once.
#   sh results/ppo/eval_unfinished.sh results/ppo/grid/a3-s0 results/ppo/grid/a4-s0 ...
set -u
for dir in "$@"; do
    nice -n 10 col ppo --eval-checkpoint --out "$dir" --eval-episodes 100 --config configs/paper.toml \
        > "$dir.eval.log" 2>&1 &
done
wait
