#!/bin/sh
# The scripted expert on a pad driving at 0.5, 1.0 and 1.5 m/s, the roof carrying the multirotor:
# straight, on a curve (0.1 rad/s) and with its speed swinging by half (period 20 s); 10 held-out
# starts each (seed 100000 on); three experts: the experiment's (lead off), leading the pad
# ([companion.pilot] lead_moving_pad), and leading it while setting down by the picture too
# (set_down_by_picture). Run from the repository.
set -e
out=results/moving-pad/lead-check
for motion in straight turn change; do
  case $motion in
    straight) extra="";;
    turn) extra="--turn-rate 0.1";;
    change) extra="--speed-change 0.5";;
  esac
  for expert in lead-off lead-on lead-picture; do
    case $expert in
      lead-off) flags="";;
      lead-on) flags="--lead-moving-pad";;
      lead-picture) flags="--lead-moving-pad --set-down-by-picture";;
    esac
    nice -n 12 python results/moving-pad/roof_carry_check.py --episodes 10 --speeds 0.5,1.0,1.5 --carries on \
      --pilots expert $extra $flags --out $out/$motion-$expert.jsonl
  done
done
