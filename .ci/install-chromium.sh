#!/usr/bin/env bash
# SPDX-License-Identifier: MIT OR Apache-2.0
# Installs Debian's headless Chromium (chromium-headless-shell: WebGPU on SwiftShader with
# --enable-unsafe-webgpu --use-webgpu-adapter=swiftshader) when it is missing, for tests/web/check_page.py.
set -euo pipefail

if command -v chromium-headless-shell >/dev/null; then
    echo "install-chromium: $(chromium-headless-shell --version) already installed"
    exit 0
fi
bash "$(dirname "$0")/apt-install.sh" install-chromium chromium-headless-shell
chromium-headless-shell --version
