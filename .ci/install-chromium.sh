#!/usr/bin/env bash
# SPDX-License-Identifier: MIT OR Apache-2.0
# Installs Debian's headless Chromium (chromium-headless-shell: WebGPU on SwiftShader with
# --enable-unsafe-webgpu --use-webgpu-adapter=swiftshader) when it is missing, for tests/web/check_page.py.
set -euo pipefail

if command -v chromium-headless-shell >/dev/null; then
    echo "install-chromium: $(chromium-headless-shell --version) already installed"
    exit 0
fi
if ! command -v apt-get >/dev/null; then
    echo "install-chromium: apt-get not found; install chromium-headless-shell (Chromium's headless shell) by hand" >&2
    exit 1
fi
sudo=()
if [ "$(id -u)" -ne 0 ]; then
    sudo=(sudo)
fi
echo "install-chromium: installing chromium-headless-shell"
"${sudo[@]}" apt-get update -q
"${sudo[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends chromium-headless-shell
chromium-headless-shell --version
