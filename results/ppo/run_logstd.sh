#!/bin/sh
# PPO with 2 actions and our initial log-std -1 (docs/baselines.md "Sensitivity": it stopped the
# drift of stable-baselines3's default, 1) to the full 1000 episodes, 3 seeds. Each run continues
# the 200-episode sensitivity run of its seed: its folder was seeded with that run's log, its
# final model as the checkpoint and "episodes": 200 (the log's length), and settings.json with
# episodes = 1000; a resumed PPO run does exactly this after any stop. Resumable like the others.
#   sh results/ppo/run_logstd.sh          (from the repository root)
set -u
OUT=${OUT:-results/ppo/logstd-m1}
run() {  # seed
    nice -n 10 col ppo --actions 2 --seed "$1" --episodes 1000 --eval-episodes 100 --log-std-init -1 \
        --config configs/paper.toml --out "$OUT/a2-s$1" >> "$OUT/a2-s$1.log" 2>&1
}
run 0 & run 1 & run 2 & wait
