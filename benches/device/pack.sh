#!/bin/bash
# Packs what benches/device/check.sh and train.sh need on a GPU machine that has no Rust toolchain: the release
# binary and the GPU parity test binary (stripped, xz), and the Vulkan loader's Debian packages. Run here, in the
# repository root, then run check.sh or train.sh there with `.devbin` and `.gl` carried (both are kept out of git
# by .git/info/exclude).
set -euo pipefail
cd "$(git rev-parse --show-toplevel)"
grep -qx '/.devbin/' .git/info/exclude 2>/dev/null || echo '/.devbin/' >> .git/info/exclude
grep -qx '/.gl/' .git/info/exclude 2>/dev/null || echo '/.gl/' >> .git/info/exclude
cargo build --release
test_bin=$(cargo test --release --features gpu --test gpu_parity --no-run --message-format=json 2>/dev/null |
    python3 -c 'import json,sys; print([m["executable"] for m in map(json.loads, sys.stdin)
        if m.get("executable") and m["target"]["name"] == "gpu_parity"][-1])')
stage=$(mktemp -d)
cp target/release/dpr-gpu "$test_bin" "$stage/"
mv "$stage/$(basename "$test_bin")" "$stage/gpu_parity"
strip "$stage"/*
rm -rf .devbin; mkdir -p .devbin .gl
# One xz stream with a 64 MiB dictionary: the weights compiled into both binaries are stored once.
(cd "$stage" && tar cf - dpr-gpu gpu_parity | xz -9 > "$OLDPWD/.devbin/bins.tar.xz")
rm -r "$stage"
if ! ls .gl/libvulkan1_*.deb > /dev/null 2>&1; then
    lists=$(mktemp -d); mkdir -p "$lists/partial"
    o="-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=$lists"
    apt-get $o update > /dev/null
    (cd .gl && apt-get $o download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
fi
du -sh .devbin .gl
