#!/bin/sh
# RL after CoL, measured: policies of CoL sessions (synthetic participant P1 on the calibrated
# task: 8 interactions = 4 demonstrations then 4 with interventions; 4 = 2 + 2) are fine-tuned
# with PPO for 100 episodes, and flown on the 100 held-out starts before and after.
#   sh results/ppo/run_finetune.sh        (from the repository root; resumable)
# how the checkpoints and datasets in $D/col8-P1 and $D/col4-P1 were made:
#   col fly --pilot synthetic:P1 --condition col --episodes 8 --config configs/paper.toml --run-dir $D/col8-P1
#   col fly --pilot synthetic:P1 --condition col --episodes 4 --config configs/paper.toml --run-dir $D/col4-P1
set -u
D=results/ppo/finetune
tune() {  # name checkpoint [options...]
    name=$1 ckpt=$2
    shift 2
    nice -n 10 col finetune "$ckpt" --episodes 100 --eval-episodes 100 --config configs/paper.toml \
        --out "$D/$name" "$@" > "$D/$name.log" 2>&1
}
case "${1:-all}" in
    col8) tune bc1 "$D/col8-P1/checkpoints/episode_007.npz" ;;
    col4) tune col4-bc1 "$D/col4-P1/checkpoints/episode_003.npz" ;;
    *) tune bc1 "$D/col8-P1/checkpoints/episode_007.npz"; tune col4-bc1 "$D/col4-P1/checkpoints/episode_003.npz" ;;
esac
