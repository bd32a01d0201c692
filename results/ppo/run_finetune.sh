#!/bin/sh
# RL after CoL, measured: the policy of a CoL session (synthetic participant P1, 8 interactions:
# 4 demonstrations then 4 with interventions, on the calibrated task) is fine-tuned with PPO for
# 100 episodes, and flown on the 100 held-out starts before and after.
#   sh results/ppo/run_finetune.sh        (from the repository root; resumable)
set -u
D=results/ppo/finetune
# how the checkpoint and dataset in $D/col8-P1 were made:
#   col fly --pilot synthetic:P1 --condition col --episodes 8 --config configs/paper.toml --run-dir $D/col8-P1
nice -n 10 col finetune "$D/col8-P1/checkpoints/episode_007.npz" --episodes 100 --eval-episodes 100 \
    --config configs/paper.toml --out "$D/bc1" > "$D/bc1.log" 2>&1
