#!/usr/bin/env bash
# SPDX-License-Identifier: MIT OR Apache-2.0
# `apt-install.sh WHO PACKAGE...`: installs Debian / Ubuntu packages with apt-get (through sudo unless root),
# non-interactively and without recommends; WHO prefixes the messages. Fails with a clear message when apt-get is
# missing. Shared by the .ci/install-*.sh scripts, which decide what is missing.
set -euo pipefail

who="$1"
shift
if ! command -v apt-get >/dev/null; then
    echo "$who: apt-get not found; install $* by hand" >&2
    exit 1
fi
sudo=()
if [ "$(id -u)" -ne 0 ]; then
    sudo=(sudo)
fi
echo "$who: installing $*"
"${sudo[@]}" apt-get update -q
"${sudo[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "$@"
