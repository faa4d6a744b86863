#!/usr/bin/env bash
# One nvidia-h200-x4 device call that trains the three tasks side by side, each resumed from a carried
# run dir (or started fresh when the dir is "-"): flat goal reaching on GPUs 0-1 (per-device learner,
# 16,384 envs), corridor on GPU 2 and spiral on GPU 3 (fewer envs, so that each env gets more of its
# 4,000/8,000-step episodes within one call). Each run lands in $OUT/<tag>.tgz (benchmarks/device/train.sh).
# Usage: WALL=seconds [EVAL_S=seconds] bash benchmarks/device/three_runs.sh FLAT_RUN CORRIDOR_RUN SPIRAL_RUN SUFFIX
set -u
flat=$1; corridor=$2; spiral=$3; suffix=$4
arg() { [ "$1" = "-" ] || echo "$1"; }
ev=${EVAL_S:-0}
CUDA_VISIBLE_DEVICES=0,1 EVAL_S=$ev TAG=flat_$suffix \
  SET="run.num_envs=16384 run.num_timesteps=1000000000 run.checkpoint_every=10000000" \
  bash benchmarks/device/train.sh configs/train_flat.yaml "$WALL" $(arg "$flat") > "$OUT/flat_$suffix.out" 2>&1 &
p1=$!
CUDA_VISIBLE_DEVICES=2 EVAL_S=$ev EVAL_EPISODES=64 TAG=corridor_$suffix \
  SET="run.num_envs=4096 run.num_timesteps=1000000000" \
  bash benchmarks/device/train.sh configs/train_corridor.yaml "$WALL" $(arg "$corridor") > "$OUT/corridor_$suffix.out" 2>&1 &
p2=$!
CUDA_VISIBLE_DEVICES=3 EVAL_S=$ev EVAL_EPISODES=64 TAG=spiral_$suffix \
  SET="run.num_envs=2048 run.num_timesteps=1000000000" \
  bash benchmarks/device/train.sh configs/train_spiral.yaml "$WALL" $(arg "$spiral") > "$OUT/spiral_$suffix.out" 2>&1 &
p3=$!
wait $p1 $p2 $p3   # the PIDs themselves (a pgrep -f loop once matched its own command line)
for t in flat corridor spiral; do echo "== $t"; tail -n 8 "$OUT/${t}_$suffix.out"; done
