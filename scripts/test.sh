#!/usr/bin/env bash
# The test command of the README: the whole suite on the default device,
# then the kernel suites again with lavapipe's 4-wide subgroups.
#
# Two streams run side by side: one test binary alone keeps about 1.4 of
# two cores busy on lavapipe (small dispatches, host work between them), so
# two at once finish sooner than one after the other (measured: 215 s in
# sequence, 161 s together; perf/RESULTS.md, twenty-ninth entry). Stream A
# is the longest binary (`train_quality`, the method end to end), the
# subgroup-4 pass, then `validation` and `train_stage3`, which balance
# the two streams (thirtieth and seventy-second entries); stream B is
# everything else. Nothing in the suite
# measures time; each stream's output is printed whole, B's as it runs and
# A's when it ends. TGS_TEST_STREAMS=1 runs them one after the other.
set -euo pipefail
cd "$(dirname "$0")/.."

bash scripts/setup.sh

# Subgroup width changes the code path of the kernels (sort, scan, raster
# forward/backward, the MLP GEMMs, the loss and light-field reductions,
# Adam and densification): their own suites compare each against its f64
# reference or the host at any width, so they run again at subgroup 4.
# The end-to-end suites (training runs, stability, the Stage II basin,
# sweeps, embedding, benches, loaders) drive the same kernels through the
# same code; a second pass of them at width 4 found nothing the kernel
# suites do not (perf/RESULTS.md, CI profile) and cost over half of CI.
# On other devices LP_NATIVE_VECTOR_WIDTH does nothing and this is a rerun.
# The second pass also keeps the CPU rasterizer at 16 x 16 tiles
# (TGS_RASTER_TILE=16; the default there is 8 x 8), so both tile sizes of
# its kernels are compared against the f64 reference.
KERNEL_SUITES=(engine sort scan raster raster_hard raster_reach kept_weights loss loss_hf mlp mlp_blocks lightfield reflection env_init train_kernels slices train_step)
# Stream A's test binaries besides the subgroup-4 pass: the first before
# it, the rest after. Stream B skips exactly their tests (listed from the
# binaries, each name checked to be unique across the workspace, so a skip
# cannot drop another binary's test of the same name).
A_BINARIES=(train_quality validation train_stage3)

a_binary() {
  local s rc=0
  s=$(date +%s)
  cargo test -p tgs-tests --test "$1" || rc=$?
  echo "== $1 took $(( $(date +%s) - s )) s"
  return $rc
}

stream_a() {
  local s rc=0 args=() b
  a_binary "${A_BINARIES[0]}" || rc=$?
  for t in "${KERNEL_SUITES[@]}"; do args+=(--test "$t"); done
  echo "== kernel suites again with LP_NATIVE_VECTOR_WIDTH=128 (lavapipe subgroup size 4), 16 x 16 tiles"
  s=$(date +%s)
  LP_NATIVE_VECTOR_WIDTH=128 TGS_RASTER_TILE=16 cargo test -p tgs-tests "${args[@]}" || rc=$?
  echo "== the subgroup-4 pass took $(( $(date +%s) - s )) s"
  for b in "${A_BINARIES[@]:1}"; do a_binary "$b" || rc=$?; done
  return $rc
}

# B's --skip arguments: every test of A's binaries, each name unique in
# the workspace (checked against the whole list).
a_skips() {
  local all names n count b
  all=$(cargo test -q --workspace -- --list --format terse 2>/dev/null | sed -n 's/: test$//p')
  for b in "${A_BINARIES[@]}"; do
    names=$(cargo test -q -p tgs-tests --test "$b" -- --list --format terse 2>/dev/null | sed -n 's/: test$//p')
    [ -n "$names" ] || { echo "test.sh: no tests listed in $b" >&2; return 1; }
    for n in $names; do
      count=$(grep -cx "$n" <<< "$all")
      [ "$count" = 1 ] || { echo "test.sh: test name '$n' of $b occurs $count times in the workspace: rename it (stream B skips it by name)" >&2; return 1; }
      printf '%s\n' --skip "$n"
    done
  done
}

# Both return the first failing cargo's status (set -e does not apply in
# a function called with ||).
stream_b() {
  local s rc=0
  s=$(date +%s)
  cargo test --workspace -- "${SKIPS[@]}" --exact || rc=$?
  echo "== the whole suite but ${A_BINARIES[*]} took $(( $(date +%s) - s )) s"
  return $rc
}

skips=$(a_skips) || { echo "== FAILED: cannot list the tests of ${A_BINARIES[*]} for stream B to skip"; exit 1; }
mapfile -t SKIPS <<< "$skips"

start=$(date +%s)
if [ "${TGS_TEST_STREAMS:-2}" = 1 ]; then
  rc=0
  stream_b || rc=$?
  stream_a || rc=$?
  [ "$rc" = 0 ] || { echo "== FAILED (exit $rc)"; exit 1; }
else
  log=$(mktemp "${TMPDIR:-/tmp}/tgs-test-stream-a.XXXXXX")
  stream_a > "$log" 2>&1 &
  pid=$!
  # Interrupted: stop stream A's cargo too (its test binary ends with it).
  trap 'pkill -TERM -P "$pid" 2>/dev/null; kill "$pid" 2>/dev/null' INT TERM
  rc_b=0
  stream_b || rc_b=$?
  rc_a=0
  wait "$pid" || rc_a=$?
  echo "== stream A (${A_BINARIES[0]}, the subgroup-4 pass, ${A_BINARIES[*]:1}), its output:"
  cat "$log"
  rm -f "$log"
  if [ "$rc_a" != 0 ] || [ "$rc_b" != 0 ]; then
    echo "== FAILED: stream A exit $rc_a, stream B exit $rc_b"
    exit 1
  fi
fi
echo "== all tests took $(( $(date +%s) - start )) s"
