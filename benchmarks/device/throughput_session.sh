#!/usr/bin/env bash
# One nvidia-h200 device call for the speed issue: the batch sweep at the shipped settings on both
# terrains, the stability runs under random actions, and two XLA-level levers at 16k envs; every step
# gets what is left of DEADLINE seconds, and everything lands in $OUT/throughput.tgz.
# Usage: [DEADLINE=560] bash benchmarks/device/throughput_session.sh
set -u
deadline=${DEADLINE:-560}; t0=$(date +%s); res="$OUT/throughput"; mkdir -p "$res"
left() { echo $(( deadline - ($(date +%s) - t0) )); }
step() {  # step NAME MIN_SECONDS BUDGET_S ARGS...: run benchmarks.throughput if MIN_SECONDS are left
  local name=$1 need=$2 budget=$3; shift 3
  if [ "$(left)" -lt "$need" ]; then echo "skip $name: $(left) s left"; return; fi
  echo "== $name ($(left) s left)"
  timeout $(( $(left) - 15 )) python3 -m benchmarks.throughput --out-dir "$res" --compile-cache /tmp/jaxcache \
    --budget-s "$budget" "$@" > "$res/$name.log" 2>&1
  echo "rc $?"; tail -n 4 "$res/$name.log"
}
step sweep 300 250 --batches 1024,4096,16384,65536 --tag shipped
step stability_flat 120 60 --terrains flat --batches 4096 --steps 100 --repeats 10 --tag stability
XLA_FLAGS=--xla_gpu_triton_gemm_any=true step xla_triton 70 10 --terrains flat --batches 16384 --tag xla_triton_gemm_any
JAX_DEFAULT_MATMUL_PRECISION=default step precision_default 70 10 --terrains flat --batches 16384 --tag matmul_default
step stability_hfield 110 30 --terrains heightfield --batches 4096 --steps 50 --repeats 5 --tag stability --append
tar czf "$OUT/throughput.tgz" -C "$OUT" throughput && rm -rf "$res"
