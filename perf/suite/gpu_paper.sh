#!/usr/bin/env bash
# Issue 77's paper-kind scenes at 400x400 on a lent GPU, in one call of at
# most ~9 minutes: every scene and seed trains Stage I, then Stage II and
# III without masks (`default`, `default-III`) and with the exact training
# masks (`masks`, `masks-III`), laid out as perf/suite/suite.py lays runs out
# (RUNS/SCENE/sSEED/...); then the viewer's frame at 800x600 and Stage I's
# iteration time on a trained 400x400 model; then, with the time left, the
# paper preset (`RUNS/paper/...`) until BUDGET, whose logs say how far it got.
#
#   here:   python3 perf/suite/mitsuba_scenes.py --out .suite/p400 --scene paper --res 400 --compact
#           for s in vehicle globe_near bookshelf house pyramid garage display; do python3 perf/suite/mitsuba_scenes.py \
#               --train-masks .suite/p400/$s --scene $s --out .suite/p400-masks/$s; done
#           cargo build --release -p tgs; the loader debs in .gl (perf/suite/gpu_suite.sh)
#   device: carry .gl .suite target/release/tgs; bash perf/suite/gpu_paper.sh
#   here:   tar xzf runs.tgz -C RUNS; python3 perf/suite/suite.py --scenes .suite/p400 \
#               --runs RUNS --seeds 0,1 --variant default --stage3   (and --variant masks
#               --seed-masks .suite/p400-masks --stage3; RUNS/paper for the paper preset)
#
# SCENES (.suite/p400), MASKS (.suite/p400-masks), SEEDS ("0 1"), PRESET
# (quick), BUDGET (seconds from the start at which everything still
# training is stopped, 480), SET (extra --set pairs for every run,
# ';'-separated, for a dry run on a CPU device), VIEW_SIZE (800x600).
set -u
here=$(pwd)
. "$(dirname "$0")/gpu_env.sh"
T=$here/target/release/tgs; S=${SCENES:-$here/.suite/p400}; M=${MASKS:-$here/.suite/p400-masks}
R=${RUNS_DIR:-/tmp/gpu-paper-runs}; OUT=${OUT:-/tmp/gpu-paper-out}
mkdir -p "$R" "$OUT"
start=$(date +%s)
left() { echo $(( ${BUDGET:-480} - ($(date +%s) - start) )); }
"$T" devices > "$OUT/devices.txt" 2>&1; cat "$OUT/devices.txt"
if [ "$TGS_DEVICE" = nvidia ] && ! grep -qi nvidia "$OUT/devices.txt"; then echo "gpu_paper: no NVIDIA device"; exit 1; fi
# train NAME OUT LOG STAGE ARGS...: one run, its wall time in times.txt;
# SET's pairs go to Stage I, its reflection./light_field. ones to II, its
# light_field. ones to III (what --from accepts).
train() {
  local name=$1 out=$2 log=$3 st=$4 t0 p extra=() kvs; shift 4
  IFS=';' read -ra kvs <<< "${SET:-}"
  for p in "${kvs[@]}"; do
    case "$st:$p" in I:?* | II:reflection.* | II:light_field.* | III:light_field.*) extra+=(--set "$p") ;; esac
  done
  t0=$(date +%s%N)
  [ "$(left)" -gt 5 ] || { echo "$name not started: out of time" | tee -a "$OUT/times.txt"; return 1; }
  if timeout "$(left)" "$T" train --out "$out" "$@" "${extra[@]}" > "$log" 2>&1; then
    echo "$name $(( ($(date +%s%N) - t0) / 1000000 )) ms" | tee -a "$OUT/times.txt"
  else
    echo "$name FAILED or stopped (see its log)" | tee -a "$OUT/times.txt"; return 1
  fi
}
chain() { # SCENE SEED: Stage I; then II and III without and with masks, side by side
  local sc=$1 s=$2 b=$R/$1/s$2 p=(--preset "${PRESET:-quick}")
  mkdir -p "$b"
  train "$sc s$s I" "$b/I" "$b/I.log" I "$S/$sc" "${p[@]}" --stages I --set "seed=$s" || return
  train "$sc s$s default" "$b/default" "$b/default.log" II "$S/$sc" --from "$b/I" --stages II &&
    train "$sc s$s default-III" "$b/default-III" "$b/default-III.log" III "$S/$sc" --from "$b/default" --stages III &
  [ -d "$M/$sc" ] && train "$sc s$s masks" "$b/masks" "$b/masks.log" II "$S/$sc" --from "$b/I" --stages II --set "reflection.seed_masks=$M/$sc" &&
    train "$sc s$s masks-III" "$b/masks-III" "$b/masks-III.log" III "$S/$sc" --from "$b/masks" --stages III
  wait
}
export -f train chain left; export T S M R OUT PRESET start BUDGET SET
scenes=$(for d in "$S"/*/; do [ -f "$d/transforms_train.json" ] && basename "$d"; done)
list=""; for s in ${SEEDS:-0 1}; do for sc in $scenes; do list+="$sc $s"$'\n'; done; done
printf '%s' "$list" | xargs -P 8 -L 1 bash -c 'chain $0 $1' 2>&1
echo "gpu_paper: suite phase done at $(( $(date +%s) - start )) s"
# Alone on the device: the viewer's frame (the first finished Stage III
# and II runs), Stage I's iteration on a trained model, and a profiled
# Stage III (GPU time per kernel in its metrics.json: at 400² Stage III ran
# ~10x slower an iteration than Stage II on the H200, fifty-eighth entry).
# The first of its arguments that holds a finished run (metrics.json).
finished() { local d; for d in "$@"; do [ -f "$d/metrics.json" ] && { echo "$d"; return; }; done; }
for v in masks-III default-III masks default; do
  run=$(finished "$R"/*/s0/"$v")
  [ -n "$run" ] && timeout 30 "$T" bench view "$run" --size "${VIEW_SIZE:-800x600}" --frames 120 2>&1 | tee -a "$OUT/bench.txt"
done
first=$(finished "$R"/*/s0/I)
[ -n "$first" ] && timeout 30 "$T" bench train --from "$first" --iterations 50 2>&1 | tee -a "$OUT/bench.txt"
two=$(finished "$R"/*/s0/masks "$R"/*/s0/default)
if [ -n "$two" ] && [ "$(left)" -gt 40 ]; then
  timeout 40 "$T" train --quiet --out "$R/profile-III" --from "$two" --stages III --set light_field.iterations=30 --set test_interval=0 --profile > "$R/profile-III.log" 2>&1 &&
    python3 -c "import json,sys; m=json.load(open(sys.argv[1])); print(json.dumps(m.get('gpu_ms_per_iteration'), indent=1)[:4000])" "$R/profile-III/metrics.json" | tee -a "$OUT/bench.txt"
fi
echo "gpu_paper: benches done at $(( $(date +%s) - start )) s"
# The paper preset with what is left (seed 0, no masks), both scenes side by side.
if [ "$(left)" -gt 30 ]; then
  for sc in $scenes; do
    ( b=$R/paper/$sc/s0; mkdir -p "$b"
      train "paper $sc s0 I" "$b/I" "$b/I.log" I "$S/$sc" --preset paper --stages I --set seed=0 &&
        train "paper $sc s0 default" "$b/default" "$b/default.log" II "$S/$sc" --from "$b/I" --stages II ) &
  done
  wait
fi
echo "gpu_paper: $(( $(date +%s) - start )) s" | tee -a "$OUT/times.txt"
# Finished runs' records and every log (an unfinished run's log says how far it got).
cd "$R" && { find . -name metrics.json | while read -r m; do d=$(dirname "$m"); for f in metrics.json stages.json run.json config.toml checkpoint-time.json; do [ -f "$d/$f" ] && printf '%s\0' "$d/$f"; done; done
  find . -name '*.log' -printf '%p\0'; } | tar --null -czf "$OUT/runs.tgz" -T -
ls -la "$OUT"
