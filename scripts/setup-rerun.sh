#!/usr/bin/env bash
# Creates (idempotently) the opt-in virtualenv holding Rerun's Python SDK and CLI (PyPI
# `rerun-sdk`), the independent viewer that scripts/rrd_check.py converts amstack's MCAP logs
# with (`rerun mcap convert`) and reads back. Opt-in because it is large: 790 MB installed
# (rerun-sdk ~500 MB, its pyarrow 26 ~170 MB and numpy 2 ~45 MB; measured with `du -sh` on a
# fresh venv), and its numpy 2 / pyarrow 26 cannot share scripts/setup-python.sh's venv (numpy
# < 2 and pyarrow 21 there). The test of the conversion (tests/tests/foxglove.rs) skips, saying
# so on stderr, when this venv is absent; AMSTACK_RERUN=1 makes it set the venv up itself.
#
#   AMSTACK_RERUN_VENV   where the venv lives (default: $HOME/.cache/amstack-rerun-venv)
#   PYTHON               the interpreter that creates it (default: python3)
#
# Prints the venv's python path on the last line of stdout.
set -euo pipefail

RERUN_VERSION="0.41.0"
VENV="${AMSTACK_RERUN_VENV:-$HOME/.cache/amstack-rerun-venv}"
PYTHON="${PYTHON:-python3}"
VPY="$VENV/bin/python"

say() { echo "setup-rerun: $*" >&2; }

mkdir -p "$(dirname "$VENV")"
if command -v flock >/dev/null 2>&1; then
    exec 9>"$VENV.lock"
    flock 9
fi

installed() {
    "$VPY" -c "import importlib.metadata as m; print(m.version('rerun-sdk'))" 2>/dev/null || true
}

if [[ -x "$VPY" && "$(installed)" == "$RERUN_VERSION" ]]; then
    say "venv $VENV already has rerun-sdk $RERUN_VERSION: nothing to do"
    echo "$VPY"
    exit 0
fi
if [[ ! -x "$VPY" ]]; then
    say "creating venv $VENV with $("$PYTHON" --version 2>&1)"
    "$PYTHON" -m venv "$VENV" >&2 || { say "'$PYTHON -m venv' failed: on Debian install python3-venv"; exit 1; }
fi
say "installing rerun-sdk==$RERUN_VERSION (about 790 MB)"
"$VPY" -m pip install --quiet --disable-pip-version-check "rerun-sdk==$RERUN_VERSION" >&2
say "done: rerun-sdk $(installed)"
echo "$VPY"
