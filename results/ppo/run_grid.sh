#!/bin/sh
# The PPO baseline grid on the calibrated task (configs/paper.toml), stable-baselines3's defaults:
# 2, 3, 4 actions x seeds 0, 1, 2 x 1000 training episodes, each final policy on the 100 held-out
# starts. Three lanes (one per seed, 2 actions first) run side by side at nice 10; every run folder
# is resumable, and a finished one (results.json) is skipped, so running this again continues
# where it stopped (logs are appended).
#   sh results/ppo/run_grid.sh            (from the repository root)
set -u
OUT=${OUT:-results/ppo/grid}
EXTRA=${EXTRA:-}  # more `col ppo` options for every run (run_logstd.sh: our initial log-std)
run() {  # actions seed
    # shellcheck disable=SC2086  # EXTRA is a list of options
    nice -n 10 col ppo --actions "$1" --seed "$2" --episodes 1000 --eval-episodes 100 $EXTRA \
        --config configs/paper.toml --out "$OUT/a$1-s$2" >> "$OUT/a$1-s$2.log" 2>&1
}
mkdir -p "$OUT"
(run 2 0; run 3 0; run 4 0) &
(run 2 1; run 3 1; run 4 1) &
(run 2 2; run 3 2; run 4 2) &
wait
