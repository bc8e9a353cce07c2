#!/usr/bin/env bash
# Creates (idempotently) the Python virtualenv that holds amstack's independent MCAP reader:
# the PyPI `mcap` package, used by scripts/mcap_check.py and by policy_runtime's tests to read
# back the files our recorder writes with code that is not ours.
#
#   AMSTACK_VENV   where the venv lives (default: $HOME/.cache/amstack-venv)
#   PYTHON         the interpreter that creates it (default: python3; needs its venv module)
#
# Re-running is cheap: when the venv already has the pinned versions it only says so.
# Prints the venv's python path on the last line of stdout.
set -euo pipefail

# Pinned: the reader must not change under the tests. mcap 1.6.0 needs lz4 and zstandard to
# decompress chunks; both ship manylinux wheels, so nothing is compiled.
MCAP_VERSION="1.6.0"
PINNED=("mcap==${MCAP_VERSION}" "lz4==4.4.5" "zstandard==0.25.0")

VENV="${AMSTACK_VENV:-$HOME/.cache/amstack-venv}"
PYTHON="${PYTHON:-python3}"
VPY="$VENV/bin/python"

say() { echo "setup-python: $*" >&2; }

# Two test binaries may call this at once: serialise on a lock beside the venv.
mkdir -p "$(dirname "$VENV")"
if command -v flock >/dev/null 2>&1; then
    exec 9>"$VENV.lock"
    flock 9
fi

installed_version() {
    "$VPY" -c 'import importlib.metadata as m; print(m.version("mcap"))' 2>/dev/null || true
}

if [[ -x "$VPY" && "$(installed_version)" == "$MCAP_VERSION" ]]; then
    say "venv $VENV already has mcap $MCAP_VERSION: nothing to do"
    echo "$VPY"
    exit 0
fi

if [[ ! -x "$VPY" ]]; then
    command -v "$PYTHON" >/dev/null 2>&1 || { say "'$PYTHON' not found: install Python 3 (apt-get install python3 python3-venv)"; exit 1; }
    say "creating venv $VENV with $("$PYTHON" --version 2>&1)"
    "$PYTHON" -m venv "$VENV" >&2 || { say "'$PYTHON -m venv' failed: on Debian install python3-venv"; exit 1; }
else
    say "venv $VENV exists but has mcap '$(installed_version)', want $MCAP_VERSION"
fi

say "installing ${PINNED[*]}"
"$VPY" -m pip install --quiet --disable-pip-version-check "${PINNED[@]}" >&2
say "done: $("$VPY" -c 'import importlib.metadata as m; print("mcap", m.version("mcap"))')"
echo "$VPY"
