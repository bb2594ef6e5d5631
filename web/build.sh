#!/usr/bin/env bash
# Builds the web package into web/pkg: the dpr-gpu-web crate for wasm32-unknown-unknown (release, no debug
# info), then wasm-bindgen's JavaScript glue (--target web). Installs the wasm32 target and wasm-bindgen-cli at
# the version web/Cargo.toml pins when they are missing (the CLI and the crate must match exactly).
set -euo pipefail
cd "$(dirname "$0")/.."

version="$(sed -n 's/^wasm-bindgen = "=\([0-9.]*\)"/\1/p' web/Cargo.toml)"
rustup target add wasm32-unknown-unknown >/dev/null
if ! wasm-bindgen --version 2>/dev/null | grep -qx "wasm-bindgen $version"; then
    echo "web/build.sh: installing wasm-bindgen-cli $version (once; a few minutes)"
    cargo install wasm-bindgen-cli --version "$version"
fi
CARGO_PROFILE_RELEASE_DEBUG=false cargo build --locked --release -p dpr-gpu-web --target wasm32-unknown-unknown
wasm-bindgen --target web --no-typescript --out-dir web/pkg target/wasm32-unknown-unknown/release/dpr_gpu_web.wasm
echo "web/build.sh: web/pkg/dpr_gpu_web_bg.wasm is $(du -k web/pkg/dpr_gpu_web_bg.wasm | cut -f1) KiB"
