#!/usr/bin/env bash
# The light field's MLP kernels on a lent GPU machine, in one call (issue
# 45: the fused kernels, TGS_MLP_GEMM=fused, against the tiled GEMM that
# GPUs run by default; bit-identical results, so only the time differs):
#
#   here:   cargo build --release -p tgs; (mkdir -p .gl && cd .gl &&
#           apt-get download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1
#           libglx0 libgles2): the Vulkan loader, and libglvnd, without
#           which NVIDIA's ICD has no vkCreateInstance (perf/suite/gpu_suite.sh);
#           the device call carries .gl and target/release/tgs
#   there:  bash perf/gpu_mlp.sh          (the benches' text in $OUT)
#
# Rows: `tgs bench mlp` for both presets at 4,096 and 65,536 samples on each
# kernel, then `tgs bench stages` (Stage III on the built-in scene) on each.
# KERNELS (default "tiled fused"; "rows" is the CPU kernel), REPS (5).
# Not run yet: by the thirtieth session's H200 rates, a few minutes.
set -u
here=$(pwd)
for f in .gl/lib{vulkan1,egl1,glvnd0,opengl0,gl1,glx0,gles2}_*.deb; do [ -f "$f" ] && dpkg -x "$f" /; done
ldconfig 2>/dev/null
export TGS_DEVICE=${TGS_DEVICE:-nvidia}
[ -f /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ] && export VK_DRIVER_FILES=${VK_DRIVER_FILES:-/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json}
T=$here/target/release/tgs
OUT=${OUT:-$here/gpu-mlp-out}
mkdir -p "$OUT"
"$T" devices > "$OUT/devices.txt" 2>&1; cat "$OUT/devices.txt"
grep -qi "$TGS_DEVICE" "$OUT/devices.txt" || { echo "gpu_mlp: no device matching '$TGS_DEVICE' (see $OUT/devices.txt)"; exit 1; }
for preset in small paper; do
    for n in 4096 65536; do
        for k in ${KERNELS:-tiled fused}; do
            echo "== mlp $preset n=$n $k"
            "$T" bench mlp --preset "$preset" --n "$n" --reps "${REPS:-5}" --gemm "$k" > "$OUT/mlp-$preset-$n-$k.txt" 2>&1 || echo "FAIL mlp $preset $n $k"
            grep '^mlp' "$OUT/mlp-$preset-$n-$k.txt"
        done
    done
done
for k in ${KERNELS:-tiled fused}; do
    echo "== stages $k"
    TGS_MLP_GEMM=$k "$T" bench stages > "$OUT/stages-$k.txt" 2>&1 || echo "FAIL stages $k"
    grep -E '^Stage|mlp' "$OUT/stages-$k.txt"
done
echo "gpu_mlp: rows in $OUT"
