#!/usr/bin/env bash
# SPDX-License-Identifier: MIT OR Apache-2.0
# Installs Mesa's software Vulkan driver (lavapipe) and the Vulkan loader on Debian / Ubuntu when they are
# missing, so the GPU parity tests have an adapter on machines without a GPU. Exports nothing: the caller
# sets DPR_GPU_REQUIRE_ADAPTER=1 and WGPU_BACKEND=vulkan.
set -euo pipefail

packages=(mesa-vulkan-drivers libvulkan1)
missing=()
for p in "${packages[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing+=("$p")
    fi
done

if [ "${#missing[@]}" -eq 0 ]; then
    echo "install-gpu: ${packages[*]} already installed"
else
    bash "$(dirname "$0")/apt-install.sh" install-gpu "${missing[@]}"
fi

if ! ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1; then
    echo "install-gpu: no lavapipe ICD in /usr/share/vulkan/icd.d after installing mesa-vulkan-drivers" >&2
    exit 1
fi
echo "install-gpu: lavapipe ICD: $(ls /usr/share/vulkan/icd.d/lvp_icd*.json | head -n 1)"
