#!/usr/bin/env bash
# SPDX-License-Identifier: MIT OR Apache-2.0
# Makes sure `python3 -m venv` works (Debian / Ubuntu ship venv and ensurepip separately, in python3-venv),
# installing python3-venv and python3-pip with apt when it does not. The Python package needs Python 3.9+.
set -euo pipefail

if ! command -v python3 >/dev/null; then
    missing=(python3 python3-venv python3-pip)
elif ! python3 -c 'import sys; sys.exit(0 if sys.version_info >= (3, 9) else 1)'; then
    echo "install-python: $(python3 --version) is older than 3.9, which the dpr_gpu package needs" >&2
    exit 1
else
    probe="$(mktemp -d)"
    if python3 -m venv "$probe/venv" >/dev/null 2>&1; then
        rm -rf "$probe"
        echo "install-python: $(python3 --version) with a working venv"
        exit 0
    fi
    rm -rf "$probe"
    missing=(python3-venv python3-pip)
fi

bash "$(dirname "$0")/apt-install.sh" install-python "${missing[@]}"
python3 -m venv --help >/dev/null
