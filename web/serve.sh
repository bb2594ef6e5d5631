#!/usr/bin/env bash
# Builds the web package (web/build.sh) and serves the repository on http://127.0.0.1:8000 (a secure context, as
# WebGPU needs): open http://127.0.0.1:8000/web/ for the page. PORT overrides the port.
set -euo pipefail
cd "$(dirname "$0")/.."
bash web/build.sh
port="${PORT:-8000}"
echo "web/serve.sh: open http://127.0.0.1:${port}/web/ (Ctrl-C stops)"
exec python3 -m http.server --bind 127.0.0.1 "$port"
