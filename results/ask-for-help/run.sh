#!/bin/sh
# How results/ask-for-help/run was made (from the repository's root): the grid of configs/ask.toml,
# replicate by replicate (resuming the same folder: the same trials as one run, complete pairs first).
set -e
for seeds in "[0]" "[0, 1]" "[0, 1, 2]"; do
  sed "s/^seeds = .*/seeds = $seeds/" configs/ask.toml > /tmp/ask-stage.toml
  nice -n 10 col experiment --config /tmp/ask-stage.toml --workers 2 --out results/ask-for-help/run
done
