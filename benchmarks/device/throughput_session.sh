#!/usr/bin/env bash
# One nvidia-h200 device call for the speed issue: the batch sweep at the shipped settings on both
# terrains, the stability runs under random actions, and two XLA-level levers at 16k envs; every step
# gets what is left of DEADLINE seconds, and everything lands in $OUT/throughput.tgz. STEPS picks and
# orders the steps (default: all, in the order below). The committed result files are copied in
# first and every step runs with --append, so a step adds or replaces its rows in them.
# Usage: [DEADLINE=560] [STEPS="sweep_hfield stability_hfield"] bash benchmarks/device/throughput_session.sh
set -u
deadline=${DEADLINE:-560}; t0=$(date +%s); res="$OUT/throughput"; mkdir -p "$res"
STEPS=${STEPS:-"sweep stability_flat xla_triton precision_default stability_hfield"}
cp benchmarks/results/throughput_nvidia_h200_*.json "$res"/ 2>/dev/null
left() { echo $(( deadline - ($(date +%s) - t0) )); }
step() {  # step NAME MIN_SECONDS BUDGET_S ARGS...: run benchmarks.throughput if MIN_SECONDS are left
  local name=$1 need=$2 budget=$3; shift 3
  if [ "$(left)" -lt "$need" ]; then echo "skip $name: $(left) s left"; return; fi
  echo "== $name ($(left) s left)"
  timeout $(( $(left) - 15 )) python3 -m benchmarks.throughput --out-dir "$res" --compile-cache /tmp/jaxcache \
    --budget-s "$budget" --append "$@" > "$res/$name.log" 2>&1
  echo "rc $?"; tail -n 4 "$res/$name.log"
}
run_steps() {  # in the order STEPS gives
  for name in $STEPS; do
    case $name in
      sweep) step sweep 300 250 --batches 1024,4096,16384,65536 --tag shipped ;;
      sweep_hfield) step sweep_hfield 150 120 --terrains heightfield --batches 16384,65536 --tag shipped ;;
      stability_flat) step stability_flat 120 60 --terrains flat --batches 4096 --steps 100 --repeats 10 --tag stability ;;
      stability_hfield) step stability_hfield 110 "${HFIELD_BUDGET:-30}" --terrains heightfield --batches 4096 --steps 50 \
                          --repeats "${HFIELD_REPEATS:-5}" --tag stability ;;
      xla_triton) XLA_FLAGS=--xla_gpu_triton_gemm_any=true step xla_triton 90 60 --terrains flat --batches 16384 \
                    --tag xla_triton_gemm_any ;;
      precision_default) JAX_DEFAULT_MATMUL_PRECISION=default step precision_default 90 60 --terrains flat \
                           --batches 16384 --tag matmul_default ;;
      *) echo "unknown step $name; steps: sweep sweep_hfield stability_flat stability_hfield xla_triton precision_default" ;;
    esac
  done
}
run_steps
tar czf "$OUT/throughput.tgz" -C "$OUT" throughput && rm -rf "$res"
