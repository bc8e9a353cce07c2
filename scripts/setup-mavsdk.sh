#!/usr/bin/env bash
# Creates (idempotently) the venv of scripts/mavsdk-check.py: MAVSDK-Python, the gRPC API
# (PyPI `mavsdk` 3.17.4, the last release of that API under this name; since 4.0 `mavsdk` is the
# native binding with another API, and the gRPC one continues as `mavsdk-grpc`). Its wheel
# ships the `mavsdk_server` binary: nothing is downloaded at run time. Opt-in, not in CI
# (about 60 MB).
#
#   AMSTACK_MAVSDK_VENV  where the venv lives (default: $HOME/.cache/amstack-mavsdk-venv)
#   PYTHON               the interpreter that creates it (default: python3)
#
# Prints the venv's python path on the last line of stdout.
set -euo pipefail

MAVSDK_VERSION="3.17.4"
VENV="${AMSTACK_MAVSDK_VENV:-$HOME/.cache/amstack-mavsdk-venv}"
PYTHON="${PYTHON:-python3}"
VPY="$VENV/bin/python"

say() { echo "setup-mavsdk: $*" >&2; }

installed() {
    "$VPY" -c "import importlib.metadata as m; print(m.version('mavsdk'))" 2>/dev/null || true
}

if [[ -x "$VPY" && "$(installed)" == "$MAVSDK_VERSION" ]]; then
    say "venv $VENV already has mavsdk $MAVSDK_VERSION"
    echo "$VPY"
    exit 0
fi
if [[ ! -x "$VPY" ]]; then
    "$PYTHON" -m venv "$VENV" >&2 || { say "'$PYTHON -m venv' failed: on Debian install python3-venv"; exit 1; }
fi
say "installing mavsdk==$MAVSDK_VERSION"
"$VPY" -m pip install --quiet --disable-pip-version-check "mavsdk==$MAVSDK_VERSION" >&2
echo "$VPY"
