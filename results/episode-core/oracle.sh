#!/usr/bin/env bash
# The episode core's oracle at one commit (RUN.md): a clean clone of the commit, run with the
# development checkout's installed packages; outputs to results/episode-core/at-<commit>/.
#   bash results/episode-core/oracle.sh [COMMIT]      (default: HEAD), from the repository's root
set -uo pipefail
root="$(pwd)"
commit="$(git rev-parse --short "${1:-HEAD}")"
clone="$(mktemp -d)/oracle-$commit"
out="$root/results/episode-core/at-$commit"
git clone -q "$root" "$clone" && git -C "$clone" checkout -q "$commit" || exit 1
mkdir -p "$out"
cd "$clone" || exit 1
export PYTHONPATH="$clone"
col="$root/.venv/bin/col"
py="$root/.venv/bin/python"
for grid in paper-grid replication human-like; do
    nice -n 5 "$col" experiment --verify "results/$grid" --trials 2 --seed 1 > "$out/verify-$grid.out" 2>&1
done
nice -n 5 "$py" -m companion.cli experiment --verify results/ask-for-help/run --trials 2 --seed 1 \
    > "$out/verify-ask-for-help.out" 2>&1
nice -n 5 "$col" fly --pilot precland --config results/precland/compare/configs/precland-px4-level-0.2.toml \
    --episodes 10 --seed 100000 --run-dir runs/precland-px4 --no-pictures > "$out/precland-precland-px4.out" 2>&1
cp runs/precland-px4/episodes.jsonl "$out/precland-px4-episodes.jsonl"
nice -n 5 "$col" fly --pilot expert --condition demo --no-learn \
    --config results/precland/compare/configs/colour-pad-level-0.2.toml \
    --episodes 10 --seed 100000 --run-dir runs/expert --no-pictures > "$out/precland-expert.out" 2>&1
cp runs/expert/episodes.jsonl "$out/expert-episodes.jsonl"
sed -i "s|$clone|.|g; s|$root|.|g" "$out"/*.out
echo "oracle at $commit: $out"
