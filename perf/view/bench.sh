#!/usr/bin/env bash
# Frame time of `tgs view`: orbit FRAMES frames (default 120) of RUN's final
# image at WxH (default 400x300) under xvfb-run; prints the device and the
# mean milliseconds a frame (the viewer's own count, from recording the
# frame to its present: render, pack, copy; the first frame included):
# once at full size (--motion-fps 0), once as a user orbits it (the
# default --motion-fps: frames drawn smaller while the camera moves).
#   bash perf/view/bench.sh RUN [WxH] [FRAMES] [TGS]
set -euo pipefail
run=${1:?usage: bench.sh RUN [WxH] [FRAMES] [TGS]}
size=${2:-400x300}
frames=${3:-120}
tgs=${4:-target/release/tgs}
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
{ for _ in $(seq "$frames"); do echo "orbit 3 0"; done; } > "$dir/path.txt"
for motion in 0 default; do
    extra=(); [ "$motion" = 0 ] && extra=(--motion-fps 0)
    out=$(xvfb-run -a -s "-screen 0 1920x1080x24" "$tgs" view "$run" --size "$size" --script "$dir/path.txt" "${extra[@]}" 2>&1) || { echo "$out"; exit 1; }
    echo "$out" | grep -E " on |frames," | sed "s/^/$size, motion-fps $motion: /"
done
