#!/usr/bin/env bash
# same-outputs.sh TGS OUT: short runs whose outputs a change that should not
# change behaviour (a refactor) must leave byte-identical. Run it with the
# binary before and after the change, then compare the two OUT directories
# with compare.py. Covers all three stages, a --from run with non-default
# Stage II/III settings (the scene-lit light with depth, geometry learning,
# normal_min_r), an orbit render and tgs eval; about a minute on lavapipe.
set -euo pipefail
TGS=$1 O=$2
rm -rf "$O"; mkdir -p "$O"
"$TGS" train --out "$O/main" --quiet --iterations 300 --set reflection.iterations=100 --set light_field.iterations=100 --set test_interval=150
"$TGS" train --out "$O/stage1" --quiet --stages I --iterations 400 --set test_interval=0
"$TGS" train --from "$O/stage1" --out "$O/from" --quiet --stages II,III --set reflection.iterations=80 --set light_field.iterations=60 \
    --set 'reflection.env_init="scene-depth"' --set reflection.lr_env=0 --set reflection.lr_quats=0.01 --set reflection.lr_scales=0.005 --set reflection.normal_min_r=0.1
"$TGS" render "$O/main" --cameras orbit --frames 3 --out "$O/orbit"
"$TGS" eval "$O/from" --out "$O/from-eval"
