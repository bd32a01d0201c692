#!/bin/sh
# Short sensitivity runs (ours, not the paper's): 2 actions, seed 0 (the last option wins:
# --seed 1 overrides it), 200 training episodes, each
# changing one of stable-baselines3's defaults, to test why the default PPO drifts away from the
# pad without ever meeting a success; compare with grid/a2-s0's first 200 episodes.
#   sh results/ppo/run_sensitivity.sh     (from the repository root; resumable)
set -u
OUT=${OUT:-results/ppo/sensitivity}
run() {  # name options...
    name=$1
    shift
    nice -n 10 col ppo --actions 2 --seed 0 --episodes 200 --eval-episodes 100 --config configs/paper.toml \
        --out "$OUT/$name" "$@" > "$OUT/$name.log" 2>&1
}
mkdir -p "$OUT"
case "${1:-all}" in
    noadvnorm) run no-adv-norm --no-normalize-advantage ;;
    logstd) run log-std-m1 --log-std-init -1 ;;
    logstd-seeds)  # two more seeds of the setting that stopped the drift
        run log-std-m1-s1 --log-std-init -1 --seed 1 & run log-std-m1-s2 --log-std-init -1 --seed 2 & wait ;;
    *) run no-adv-norm --no-normalize-advantage & run log-std-m1 --log-std-init -1 & wait ;;
esac
