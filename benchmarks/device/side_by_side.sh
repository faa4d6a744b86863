#!/usr/bin/env bash
# Several training runs side by side in one device call, one process per GPU group (processes that
# share a GPU take turns: one run per GPU or group of GPUs). Each run is one quoted spec,
#   "GPUS|TAG|CONFIG|SET|RESUME|INIT_FROM|EVAL_EPISODES"
# GPUS: CUDA_VISIBLE_DEVICES (e.g. 0,1); SET: space-separated --set overrides; RESUME / INIT_FROM: a
# carried run dir or "-"; EVAL_EPISODES: 0 skips the evaluation. Each run lands in $OUT/<TAG>.tgz
# (benchmarks/device/train.sh); WALL (s) bounds training, EVAL_S (s) each evaluation.
# Usage: WALL=480 EVAL_S=60 bash benchmarks/device/side_by_side.sh SPEC [SPEC ...]
set -u
pids=()
for spec in "$@"; do
  IFS='|' read -r gpus tag config set resume init episodes <<< "$spec"
  [ "$resume" = "-" ] && resume=""
  [ "$init" = "-" ] && init=""
  ev=${EVAL_S:-0}; [ "${episodes:-0}" -gt 0 ] || ev=0
  CUDA_VISIBLE_DEVICES=$gpus TAG=$tag SET="$set" INIT_FROM="$init" EVAL_S=$ev EVAL_EPISODES=${episodes:-0} \
    bash benchmarks/device/train.sh "$config" "$WALL" $resume > "$OUT/$tag.out" 2>&1 &
  pids+=($!)
done
wait "${pids[@]}"   # the PIDs themselves (a pgrep -f loop once matched its own command line)
for spec in "$@"; do tag=$(cut -d'|' -f2 <<< "$spec"); echo "== $tag"; tail -n 8 "$OUT/$tag.out"; done
