#!/usr/bin/env bash
# Creates (idempotently) the opt-in Python virtualenv of `amstack sweep --engine ray`: the PyPI
# `ray` package (core only: tasks, the object store, the `ray start` cluster command), which
# scripts/ray_sweep.py drives. It is large (~200 MB installed), so it has a venv of its own and
# nothing else installs it.
#
#   AMSTACK_RAY_VENV   where the venv lives (default: $HOME/.cache/amstack-ray-venv)
#   PYTHON             the interpreter that creates it (default: python3; needs its venv module)
#
# Every node of a Ray cluster that runs amstack shards needs the same Ray version: run this
# script (or `pip install ray==<RAY_VERSION>`) on each of them.
# Re-running is cheap: when the venv already has the pinned version it only says so.
# Prints the venv's python path on the last line of stdout.
set -euo pipefail

# Pinned: head, workers and driver must run the same Ray.
RAY_VERSION="2.60.0"

VENV="${AMSTACK_RAY_VENV:-$HOME/.cache/amstack-ray-venv}"
PYTHON="${PYTHON:-python3}"
VPY="$VENV/bin/python"

say() { echo "setup-ray: $*" >&2; }

mkdir -p "$(dirname "$VENV")"
if command -v flock >/dev/null 2>&1; then
    exec 9>"$VENV.lock"
    flock 9
fi

installed() {
    "$VPY" -c "import importlib.metadata as m; print(m.version('ray'))" 2>/dev/null || true
}

if [[ -x "$VPY" && "$(installed)" == "$RAY_VERSION" ]]; then
    say "venv $VENV already has ray $RAY_VERSION: nothing to do"
    echo "$VPY"
    exit 0
fi

if [[ ! -x "$VPY" ]]; then
    command -v "$PYTHON" >/dev/null 2>&1 || { say "'$PYTHON' not found: install Python 3 (apt-get install python3 python3-venv)"; exit 1; }
    say "creating venv $VENV with $("$PYTHON" --version 2>&1)"
    "$PYTHON" -m venv "$VENV" >&2 || { say "'$PYTHON -m venv' failed: on Debian install python3-venv"; exit 1; }
else
    say "venv $VENV exists but has ray '$(installed)', want $RAY_VERSION"
fi

say "installing ray==$RAY_VERSION"
"$VPY" -m pip install --quiet --disable-pip-version-check "ray==${RAY_VERSION}" >&2
say "done: ray $(installed)"
echo "$VPY"
