#!/usr/bin/env bash
# Train on the GPU machine within one device call, then evaluate; everything lands in $OUT/<name>.tgz.
# Usage (from the repo root, after the wheel install line):
#   [TAG=name] [SET="key=value ..."] [CUDA_VISIBLE_DEVICES=...] \
#   bash benchmarks/device/train.sh CONFIG WALL_SECONDS [RESUME_RUN_DIR]
# TAG names the archive (default: the config's name), SET adds `--set` overrides; several runs can
# share one machine's GPUs at once with CUDA_VISIBLE_DEVICES and distinct TAGs. EVAL_S bounds the
# evaluation (default 240 s; 0 skips it), EVAL_EPISODES its episode count (default 128).
# Training gets SIGINT after WALL_SECONDS (it finishes the epoch and writes a checkpoint).
# With RESUME_RUN_DIR (a run dir carried to the device) the run continues from its checkpoint;
# INIT_FROM (a carried run dir) starts a new run from its networks (--init-from).
set -u
config=$1; wall=$2; resume=${3:-}
name=${TAG:-$(basename "$config" .yaml)}
out=${OUT:-/tmp/out}/$name
mkdir -p "$out"
run="$out/run"
args=(--config "$config" --run-dir "$run")
if [ -n "$resume" ]; then cp -r "$resume" "$run"; args+=(--resume); fi
if [ -n "${INIT_FROM:-}" ]; then args+=(--init-from "$INIT_FROM"); fi
for kv in ${SET:-}; do args+=(--set "$kv"); done
export JAX_DEFAULT_MATMUL_PRECISION=highest   # no TF32 in the physics (DESIGN_NOTES)
export XLA_PYTHON_CLIENT_PREALLOCATE=false
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv > "$out/gpu.txt" 2>&1
python3 -c "import jax, mujoco, brax; print('jax', jax.__version__, 'mujoco', mujoco.__version__, 'brax', brax.__version__, jax.devices())" >> "$out/gpu.txt" 2>&1
start=$(date +%s)
timeout -s INT -k 60 "$wall" python3 -m train "${args[@]}" 2>&1 | tr '\r' '\n' | tail -n 400 > "$out/train.log"
echo "train exit ${PIPESTATUS[0]} after $(( $(date +%s) - start )) s" >> "$out/train.log"
tail -n 25 "$out/train.log"
rm -rf "$run/tensorboard"
if [ "${EVAL_S:-240}" -gt 0 ]; then
  timeout "${EVAL_S:-240}" python3 -m train.evaluate "$run" --episodes "${EVAL_EPISODES:-128}" 2>&1 | tail -n 20 | tee "$out/eval.log"
fi
# the device tool returns few files and few folder levels: pack everything into one archive
tar czf "${OUT:-/tmp/out}/$name.tgz" -C "${OUT:-/tmp/out}" "$name" && rm -rf "$out"
