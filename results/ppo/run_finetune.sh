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
C4="$D/col4-P1/checkpoints/episode_003.npz"
# Sensitivity and ablation (ours) from the CoL@4 policy: stable-baselines3's initial action noise
# (log-std 0) instead of -1.5, and no behaviour-cloning term. The "before" evaluation is the same
# checkpoint on the same starts, so it is copied from col4-bc1 rather than flown again.
same_before() { mkdir -p "$D/$1" && cp "$D/col4-bc1/before.json" "$D/$1/before.json"; }
case "${1:-all}" in
    col8) tune bc1 "$D/col8-P1/checkpoints/episode_007.npz" ;;
    col4) tune col4-bc1 "$C4" ;;
    col4-logstd0) same_before col4-logstd0; tune col4-logstd0 "$C4" --episodes 50 --log-std-init 0 ;;
    col4-nobc) same_before col4-nobc; tune col4-nobc "$C4" --bc-weight 0 ;;
    # Two more fine-tuning seeds of both CoL@4 rows, in two lanes. A seed also moves the
    # training starts (episode i starts from seed + i), so seeds 1000 and 2000 train on starts
    # that no other row used.
    col4-seeds)
        (for s in 1000 2000; do same_before "col4-bc1-s$s"; tune "col4-bc1-s$s" "$C4" --seed "$s"; done) &
        (for s in 1000 2000; do same_before "col4-nobc-s$s"; tune "col4-nobc-s$s" "$C4" --bc-weight 0 --seed "$s"; done) &
        wait ;;
    # The other synthetic participants: a CoL@4 session each (made here if its folder is
    # missing), then its policy fine-tuned with and without the behaviour-cloning term (seed 0),
    # in two lanes. Only the final checkpoint, episodes.jsonl and human.csv are kept.
    col4-participants)
        for P in P2 P3 P4; do
            if [ ! -f "$D/col4-$P/checkpoints/episode_003.npz" ]; then
                nice -n 10 col fly --pilot "synthetic:$P" --condition col --episodes 4 --config configs/paper.toml \
                    --run-dir "$D/col4-$P" > "$D/col4-$P.log" 2>&1
            fi
        done
        (for P in P2 P3 P4; do tune "col4-$P-bc1" "$D/col4-$P/checkpoints/episode_003.npz"; done) &
        (for P in P2 P3 P4; do tune "col4-$P-nobc" "$D/col4-$P/checkpoints/episode_003.npz" --bc-weight 0; done) &
        wait ;;
    *) tune bc1 "$D/col8-P1/checkpoints/episode_007.npz"; tune col4-bc1 "$C4"
       same_before col4-logstd0; tune col4-logstd0 "$C4" --episodes 50 --log-std-init 0
       same_before col4-nobc; tune col4-nobc "$C4" --bc-weight 0 ;;
esac
