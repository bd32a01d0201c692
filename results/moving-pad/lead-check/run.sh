#!/bin/sh
# The scripted expert with and without [companion.pilot] lead_moving_pad on a pad driving at 0.5, 1.0
# and 1.5 m/s, the roof carrying the multirotor: straight, on a curve (0.1 rad/s) and with its speed
# swinging by half (period 20 s); 10 held-out starts each (seed 100000 on). Run from the repository.
set -e
out=results/moving-pad/lead-check
for motion in straight turn change; do
  case $motion in
    straight) extra="";;
    turn) extra="--turn-rate 0.1";;
    change) extra="--speed-change 0.5";;
  esac
  for lead in off on; do
    flag=""; [ $lead = on ] && flag="--lead-moving-pad"
    nice -n 12 python results/moving-pad/roof_carry_check.py --episodes 10 --speeds 0.5,1.0,1.5 --carries on \
      --pilots expert $extra $flag --out $out/$motion-lead-$lead.jsonl
  done
done
