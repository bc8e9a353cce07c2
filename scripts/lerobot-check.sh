#!/usr/bin/env bash
# Opt-in check that the learning stack loads a dataset amstack wrote: the PyPI `lerobot`
# package (in a virtualenv of its own: it pulls PyTorch, several GB) opens DIR with
# `LeRobotDataset(repo_id, root=DIR)` and its frames' state, action, task and images are
# compared with what amstack wrote (read with pyarrow).
#
#   scripts/lerobot-check.sh DIR [more DIRs]
#
#   LEROBOT_VERSION  the lerobot release (default 0.4.4, the reference's; the newest for
#                    Python 3.11 on PyPI as of 2026-11)
#   LEROBOT_VENV     where the venv lives (default: $HOME/.cache/amstack-lerobot-venv)
#   PYTHON           the interpreter that creates it (default: python3)
set -euo pipefail

[[ $# -ge 1 ]] || { echo "usage: $0 DIR [DIR...]" >&2; exit 2; }
LEROBOT_VERSION="${LEROBOT_VERSION:-0.4.4}"
VENV="${LEROBOT_VENV:-$HOME/.cache/amstack-lerobot-venv}"
PYTHON="${PYTHON:-python3}"
VPY="$VENV/bin/python"
say() { echo "lerobot-check: $*" >&2; }

have=$("$VPY" -c "import importlib.metadata as m; print(m.version('lerobot'))" 2>/dev/null || true)
if [[ "$have" != "$LEROBOT_VERSION" ]]; then
    [[ -x "$VPY" ]] || "$PYTHON" -m venv "$VENV"
    say "installing lerobot==$LEROBOT_VERSION into $VENV (PyTorch included: large)"
    "$VPY" -m pip install --quiet --disable-pip-version-check "lerobot==$LEROBOT_VERSION" >&2
fi
say "lerobot $("$VPY" -c "import importlib.metadata as m; print(m.version('lerobot'))")"
export HF_HUB_OFFLINE=1 HF_DATASETS_OFFLINE=1
status=0
for dir in "$@"; do
    "$VPY" "$(dirname "$0")/lerobot_check.py" "$dir" || status=1
done
exit $status
