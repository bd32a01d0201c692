#!/bin/sh
# PPO with our initial log-std -1 (docs/baselines.md "Sensitivity": it stopped the drift of
# stable-baselines3's default, 0) for 2, 3 and 4 actions x seeds 0, 1, 2 x 1000 episodes; three
# lanes, one per seed. Each 2-action run continues the 200-episode sensitivity run of its seed:
# its folder was seeded with that run's log, its final model as the checkpoint and
# "episodes": 200 (the log's length), and settings.json with episodes = 1000; a resumed PPO run
# does exactly this after any stop. Resumable like the others; finished runs are skipped.
#   sh results/ppo/run_logstd.sh          (from the repository root)
set -u
OUT=${OUT:-results/ppo/logstd-m1} EXTRA="--log-std-init -1" exec sh "$(dirname "$0")/run_grid.sh"
