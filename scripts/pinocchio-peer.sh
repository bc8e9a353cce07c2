#!/usr/bin/env bash
# Opt-in peer check of amstack's rigid-body dynamics (platform::ArticulatedBody: CRBA mass
# matrix, RNEA bias forces, forward dynamics through M's LᵀDL factor) against Pinocchio, a dynamics library that is not ours, on the five
# built-in vehicles' URDFs. Not part of CI: Pinocchio's wheels and their cmeel prefix (Boost,
# hpp-fcl, assimp) take ~440 MB, so it lives in its own venv.
#
#   bash scripts/pinocchio-peer.sh [SAMPLES] [SEED]     (defaults 50, 0)
#
#   AMSTACK        the amstack binary (default: build the release binary with cargo)
#   AMSTACK_PIN_VENV  the venv (default: $HOME/.cache/amstack-pin-venv)
#
# Writes `amstack platforms --dynamics` to a temporary file and prints, per vehicle, the largest
# difference of M, of b and of the forward dynamics from Pinocchio's (`crba`, `rnea` with zero
# acceleration, `aba`) over the samples; exits 1 if any exceeds 1e-9 relative to the largest
# entry.
set -euo pipefail
SAMPLES="${1:-50}"
SEED="${2:-0}"
HERE="$(cd "$(dirname "$0")" && pwd)"
ROOT="$(dirname "$HERE")"
VENV="${AMSTACK_PIN_VENV:-$HOME/.cache/amstack-pin-venv}"
# numpy < 2 resolves pin 2.7.0 (manylinux wheels, nothing compiled).
PINNED=("pin==2.7.0" "numpy==1.26.4")

say() { echo "pinocchio-peer: $*" >&2; }

if [[ ! -x "$VENV/bin/python" ]]; then
    command -v python3 >/dev/null 2>&1 || { say "python3 not found: apt-get install python3 python3-venv"; exit 1; }
    say "creating venv $VENV"
    python3 -m venv "$VENV" >&2
fi
if ! "$VENV/bin/python" -c "import importlib.metadata as m; assert m.version('pin') == '2.7.0'" 2>/dev/null; then
    say "installing ${PINNED[*]}"
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check "${PINNED[@]}" >&2
fi

if [[ -z "${AMSTACK:-}" ]]; then
    say "building amstack (release)"
    (cd "$ROOT" && cargo build --release --quiet >&2)
    AMSTACK="${CARGO_TARGET_DIR:-$ROOT/target}/release/amstack"
fi
OUT="$(mktemp -d)"
trap 'rm -rf "$OUT"' EXIT
"$AMSTACK" platforms --dynamics "$OUT/dynamics.json" --samples "$SAMPLES" --seed "$SEED" >/dev/null
"$VENV/bin/python" "$HERE/pinocchio_peer.py" "$OUT/dynamics.json" "$ROOT/platform/vehicles"
