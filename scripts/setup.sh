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
  libfontconfig-dev libfreetype-dev fonts-dejavu-core   # text in the sweep's plots (plotters)
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
