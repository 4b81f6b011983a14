#!/usr/bin/env bash
# The glass-scene suite on a lent GPU machine, in one call: for every scene
# and seed, Stage I (quick preset), then each Stage II variant from it, the
# way perf/suite/suite.py lays runs out (RUNS/SCENE/sSEED/{I,VARIANT}); the
# runs' metrics, configs and logs come back as one archive that suite.py
# then tabulates here without training anything:
#
#   here:   cp -r SUITE_DATASETS .suite/s50; build target/release/tgs;
#           (cd .gl && apt-get download libvulkan1 libegl1 libglvnd0
#           libopengl0 libgl1 libglx0 libgles2): the loader, and libglvnd,
#           without which NVIDIA's ICD has no vkCreateInstance; the device
#           call carries .gl, .suite and target/release/tgs (which links
#           only the C library)
#   there:  bash perf/suite/gpu_suite.sh          (writes $OUT/runs.tgz)
#   here:   tar xzf runs.tgz -C RUNS && python3 perf/suite/suite.py \
#               --scenes SUITE_DATASETS --runs RUNS --seeds 0,1 --variant ...
#
# SCENES (default .suite/s50), SEEDS ("0 1"), PAR (parallel scene-seed
# chains, 16), BUDGET (seconds before unfinished chains are stopped, 390).
# Measured on an H200 (perf/RESULTS.md, thirtieth entry): 16 chains side by
# side take 205 s for their Stage I and 30-60 s per Stage II variant; the
# GPU serves the processes in turn, so more chains do not finish sooner.
set -u
here=$(pwd)
. "$(dirname "$0")/gpu_env.sh"
T=$here/target/release/tgs; R=/tmp/gpu-suite-runs; S=${SCENES:-$here/.suite/s50}
mkdir -p "$R" "$OUT"
"$T" devices > "$OUT/devices.txt" 2>&1; cat "$OUT/devices.txt"
grep -qi nvidia "$OUT/devices.txt" || { echo "gpu_suite: no NVIDIA device (see $OUT/devices.txt)"; exit 1; }
G='reflection.lr_quats=1e-2;reflection.lr_scales=5e-3'
VARIANTS=${VARIANTS:-"default: geom:$G scenelight_geom:reflection.env_init=\"scene\";reflection.lr_env=0;$G grad_geom:reflection.seed_normal=\"gradient\";$G copy_geom:reflection.init=\"copy\";$G copyhull_geom:reflection.init=\"copy+hull\";$G"}
chain() { # SCENE SEED: Stage I, then every variant's Stage II from it
  local sc=$1 s=$2 b=$R/$1/s$2 t0 v n kv p
  mkdir -p "$b"
  t0=$(date +%s%N)
  "$T" train --quiet --out "$b/I" "$S/$sc" --stages I --set "seed=$s" > "$b/I.log" 2>&1 || { echo "FAIL $sc s$s I"; return; }
  echo "$sc s$s I $(( ($(date +%s%N) - t0) / 1000000 )) ms"
  for v in $VARIANTS; do
    n=${v%%:*}; kv=${v#*:}; local args=()
    IFS=';' read -ra kvs <<< "$kv"; for p in "${kvs[@]}"; do [ -n "$p" ] && args+=(--set "$p"); done
    t0=$(date +%s%N)
    "$T" train --quiet --out "$b/$n" "$S/$sc" --from "$b/I" --stages II "${args[@]}" > "$b/$n.log" 2>&1 || echo "FAIL $sc s$s $n"
    echo "$sc s$s $n $(( ($(date +%s%N) - t0) / 1000000 )) ms"
  done
}
export -f chain; export T R S VARIANTS
list=""
for s in ${SEEDS:-0 1}; do for sc in $(ls "$S"); do [ -f "$S/$sc/transforms_train.json" ] && list+="$sc $s"$'\n'; done; done
start=$(date +%s)
printf '%s' "$list" | timeout "${BUDGET:-390}" xargs -P "${PAR:-16}" -L 1 bash -c 'chain $0 $1' 2>&1 | tee "$OUT/times.txt"
echo "gpu_suite: $(( $(date +%s) - start )) s"
# Unfinished runs (no metrics.json) stay out of the archive: suite.py would refuse them.
cd "$R" && find . -name metrics.json | while read -r m; do
  d=$(dirname "$m")
  for f in "$d"/metrics.json "$d"/stages.json "$d"/run.json "$d"/config.toml "$d"/checkpoint-time.json "$d.log"; do [ -f "$f" ] && printf '%s\0' "$f"; done
done | tar --null -czf "$OUT/runs.tgz" -T -
ls -la "$OUT"
