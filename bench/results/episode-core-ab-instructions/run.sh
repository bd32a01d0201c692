#!/usr/bin/env bash
# The episode core's A/B by instruction counts (valgrind cachegrind, "I refs"): the same work at
# two commits, counted, not timed, so the figure does not depend on the machine's load.
#   BEFORE=clone-of-2ac8ca0 AFTER=clone-of-5c78759 CHECKPOINT=P2-CoL@4.npz bash run.sh > ir.jsonl
# The checkpoint: P2's CoL trained 4 episodes (configs/paper.toml, replicate 0) by the after clone.
# Per step: (I refs of N starts - I refs of 2 starts) / (their steps' difference), so the start-up
# (imports, SITL, renderer) drops out; rl_env_speed.py likewise between --steps 400 and 2000.
set -u
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
HERE=$(cd "$(dirname "$0")" && pwd)
PY=${PY:-python}
ir() { # side label cmd...
  local side=$1 label=$2; shift 2
  local dir; dir=$([ "$side" = before ] && echo "$BEFORE" || echo "$AFTER")
  local log; log=$(cd "$dir" && PYTHONPATH=$dir valgrind --tool=cachegrind --cache-sim=no --cachegrind-out-file=/dev/null "$@" 2>&1)
  local refs; refs=$(echo "$log" | grep -E "I\s+refs" | tr -d ',' | awk '{print $NF}')
  local steps; steps=$(echo "$log" | grep -E "^steps" | awk '{print $2}')
  echo "{\"side\": \"$side\", \"label\": \"$label\", \"ir\": $refs, \"steps\": \"${steps}\"}"
}
for round in 1 2; do
  for side in before after; do
    dir=$([ "$side" = before ] && echo "$BEFORE" || echo "$AFTER")
    for mode in session batched; do
      for n in 2 8; do ir $side "eval-$mode-$n" $PY "$HERE/eval_n.py" "$dir" $mode $n; done
    done
    for part in inprocess_env batched_8_envs_in_1_process; do
      for s in 400 2000; do ir $side "rl-$part-$s" $PY bench/rl_env_speed.py --parts $part --steps $s; done
    done
  done
done
