#!/usr/bin/env bash
# The test command of the README: the whole suite on the default device,
# then the kernel suites again with lavapipe's 4-wide subgroups.
set -euo pipefail
cd "$(dirname "$0")/.."

bash scripts/setup.sh

s=$(date +%s)
cargo test --workspace
echo "== the whole suite took $(( $(date +%s) - s )) s"

# Subgroup width changes the code path of the kernels (sort, scan, raster
# forward/backward, the MLP GEMMs, the loss and light-field reductions,
# Adam and densification): their own suites compare each against its f64
# reference or the host at any width, so they run again at subgroup 4.
# The end-to-end suites (training runs, stability, the Stage II basin,
# sweeps, embedding, benches, loaders) drive the same kernels through the
# same code; a second pass of them at width 4 found nothing the kernel
# suites do not (perf/RESULTS.md, CI profile) and cost over half of CI.
# On other devices LP_NATIVE_VECTOR_WIDTH does nothing and this is a rerun.
KERNEL_SUITES=(engine sort scan raster raster_hard loss loss_hf mlp lightfield reflection env_init train_kernels train_step)
args=()
for t in "${KERNEL_SUITES[@]}"; do args+=(--test "$t"); done
echo "== kernel suites again with LP_NATIVE_VECTOR_WIDTH=128 (lavapipe subgroup size 4)"
s=$(date +%s)
LP_NATIVE_VECTOR_WIDTH=128 cargo test -p tgs-tests "${args[@]}"
echo "== the subgroup-4 pass took $(( $(date +%s) - s )) s"
