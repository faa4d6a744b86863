#!/usr/bin/env bash
# One device call for the multi-GPU work: find XLA flags under which the pmapped training env
# compiles on every local GPU (benchmarks/device/pmap_check.py), then run the scaling benchmark and a
# short 4-GPU resume of FLAT_RUN; if no flags work, localise the crash and train on single GPUs.
# Usage: bash benchmarks/device/multi_gpu_session.sh FLAT_RUN CORRIDOR_RUN   (results under $OUT)
set -u
flat=$1; corridor=$2
P="python3 benchmarks/device/pmap_check.py"
fix=""
for v in "" "--xla_gpu_autotune_level=0" "--xla_gpu_enable_command_buffer=" \
         "--xla_gpu_autotune_level=0 --xla_gpu_enable_command_buffer="; do
  echo "== auto_step XLA_FLAGS=[$v]"
  if XLA_FLAGS="$v" timeout 100 $P auto_step > "$OUT/pmap_check.log" 2>&1; then
    fix=1; export XLA_FLAGS="$v"; tail -n 1 "$OUT/pmap_check.log"; break
  else echo "rc $?"; grep -m 2 -i "fault\|error" "$OUT/pmap_check.log"; fi
done
if [ -n "$fix" ]; then
  timeout 300 python3 -m benchmarks.scaling --budget-s 230 --tag nvidia_h200_x4 --out-dir "$OUT" > "$OUT/scaling.log" 2>&1
  echo "scaling rc $?"; tail -n 12 "$OUT/scaling.log"
  EVAL_S=0 TAG=flat_4gpu bash benchmarks/device/train.sh configs/train_flat.yaml 130 "$flat" > "$OUT/flat_4gpu.out" 2>&1
  tail -n 6 "$OUT/flat_4gpu.out"
else
  for p in forward env_reset jit_sharded_reset; do timeout 60 $P $p > "$OUT/piece_$p.log" 2>&1; echo "$p rc $?"; done
  CUDA_VISIBLE_DEVICES=0 EVAL_S=0 TAG=flat_1gpu_b bash benchmarks/device/train.sh configs/train_flat.yaml 260 "$flat" > "$OUT/flat_1gpu_b.out" 2>&1 &
  CUDA_VISIBLE_DEVICES=1 EVAL_S=0 TAG=corridor_b bash benchmarks/device/train.sh configs/train_corridor.yaml 260 "$corridor" > "$OUT/corridor_b.out" 2>&1 &
  wait; tail -n 6 "$OUT"/*_b.out
fi
