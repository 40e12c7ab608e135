#!/usr/bin/env bash
# Sets up hack-render on a fresh Debian (bookworm or newer) machine as root, using only
# the package registries. Idempotent: re-running it skips what is already there.
#   bash scripts/setup.sh          # runtime
#   bash scripts/setup.sh --test   # runtime + test and fitting extras (pytest, Ray, mkdocs + material + mkdocstrings)
set -euo pipefail
cd "$(dirname "$0")/.."
extras="fit,denoise"  # denoise: Intel Open Image Denoise (pyoidn, ~170 MB) for --denoise
[[ "${1:-}" == "--test" ]] && extras="fit,denoise,test"

SUDO=""; [[ $(id -u) -ne 0 ]] && SUDO="sudo"
# Mitsuba's CPU backend (llvm_ad_rgb) needs a system LLVM; 14/15 abort with
# "Cannot select: fminimum", so install LLVM 19. ffmpeg comes from imageio-ffmpeg.
if ! ldconfig -p 2>/dev/null | grep -q 'libLLVM.so.19\|libLLVM-19'; then
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq libllvm19 >/dev/null
fi
PY=${PYTHON:-python3}
# torch first, pinned: the CPU build lies on disk; an open range would pull a CUDA build.
$PY -m pip install -q "torch==2.13.0"
$PY -m pip install -q -e ".[${extras}]"
# export tests (tests/test_export_*.py): node + the Khronos glTF-Validator (npm) check every
# exported glTF; Debian's chromium, headless, drives the viewer. Tests skip without them.
if [[ "${1:-}" == "--test" ]]; then
  need=()
  command -v node >/dev/null || need+=(nodejs)
  command -v npm >/dev/null || need+=(npm)
  command -v chromium >/dev/null || need+=(chromium)
  if ((${#need[@]})); then
    export DEBIAN_FRONTEND=noninteractive
    $SUDO apt-get update -qq
    $SUDO apt-get install -y -qq "${need[@]}" >/dev/null
  fi
  [[ -d "$(npm root -g)/gltf-validator" ]] || $SUDO npm install -g --no-audit --no-fund -q gltf-validator@2.0.0-dev.3.10
fi
