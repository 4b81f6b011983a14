# Sourced by the scripts that run on a lent NVIDIA machine (gpu_suite.sh,
# gpu_paper.sh), from the repository root: TGS_DEVICE (default nvidia),
# and for it the Vulkan loader and libglvnd (which NVIDIA's ICD needs)
# unpacked from .gl, and NVIDIA's ICD where the machine has it. Another
# TGS_DEVICE (llvmpipe, for a dry run on a CPU) leaves the system alone.
export TGS_DEVICE=${TGS_DEVICE:-nvidia}
if [ "$TGS_DEVICE" = nvidia ]; then
  for f in .gl/lib{vulkan1,egl1,glvnd0,opengl0,gl1,glx0,gles2}_*.deb; do [ -f "$f" ] && dpkg -x "$f" /; done
  ldconfig
fi
[ -f /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ] && export VK_DRIVER_FILES=${VK_DRIVER_FILES:-/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json}
