#!/usr/bin/env bash
# Creates (idempotently) the Python virtualenv that holds amstack's third-party checkers:
# - the PyPI `mcap` package, used by scripts/mcap_check.py and by policy_runtime's tests to read
#   back the files our recorder writes with code that is not ours;
# - `pymavlink`, the ground station of scripts/mavlink_gcs.py, used by tests/tests/mavlink.rs
#   to talk to the twin's autopilot (`amstack twin serve --mavlink`) with a MAVLink
#   implementation that is not ours;
# - `imageio-ffmpeg`, whose wheel ships a static ffmpeg program: the video encoder of the
#   tests of `--video` (AMSTACK_FFMPEG) on a machine without Debian's ffmpeg, and the
#   independent reader that counts an MP4's frames.
# - `pyarrow` and `numpy`, the independent reader of the LeRobot datasets `amstack record`
#   writes (scripts/dataset_check.py, run by tests/tests/dataset.rs).
# - `openpi-client` (its `msgpack_numpy` is the wire encoding of openpi's policy server), the
#   encoding of scripts/openpi_server.py, the policy server tests/tests/policy.rs starts;
# - `onnx` and `onnxruntime`, which make the test ONNX models (scripts/onnx_model.py) and give
#   the reference outputs amstack's tract inference is checked against.
#
# - `scikit-learn` (with scipy, joblib, threadpoolctl), the behaviour-cloning trainer of
#   scripts/train_policy.py (record -> train -> evaluate, tests/tests/policy.rs): an MLP on 2
#   CPU cores in seconds, exported to ONNX with the `onnx` helper API. +202 MB installed (measured),
#   where PyTorch's CPU wheels are ~10x that.
#
#   AMSTACK_VENV   where the venv lives (default: $HOME/.cache/amstack-venv)
#   PYTHON         the interpreter that creates it (default: python3; needs its venv module)
#
# Re-running is cheap: when the venv already has the pinned versions it only says so.
# Prints the venv's python path on the last line of stdout.
set -euo pipefail

# Pinned: the reader must not change under the tests. mcap 1.6.0 needs lz4 and zstandard to
# decompress chunks; both ship manylinux wheels, so nothing is compiled. pymavlink 2.4.50
# ships a manylinux wheel too and needs lxml and fastcrc (wheels). numpy stays below 2: the
# policies' openpi-client (same venv) requires numpy < 2, and pyarrow 21 runs on it (26 does not).
MCAP_VERSION="1.6.0"
PYMAVLINK_VERSION="2.4.50"
PYARROW_VERSION="21.0.0"
IMAGEIO_FFMPEG_VERSION="0.8.1"
# openpi-client 0.1.2 brings msgpack, numpy, websockets, pillow, dm-tree (all wheels); pillow
# is pinned too: scripts/dataset_check.py reads the openpi export's PNGs with it.
# onnx/onnxruntime ship manylinux wheels (protobuf, ml_dtypes, flatbuffers).
OPENPI_CLIENT_VERSION="0.1.2"
ONNXRUNTIME_VERSION="1.32.0"
SKLEARN_VERSION="1.9.1"
PINNED=("mcap==${MCAP_VERSION}" "lz4==4.4.5" "zstandard==0.25.0"
        "pymavlink==${PYMAVLINK_VERSION}" "lxml==6.1.3" "fastcrc==0.5.0"
        "imageio-ffmpeg==${IMAGEIO_FFMPEG_VERSION}"
        "pyarrow==${PYARROW_VERSION}" "numpy==1.26.4"
        "openpi-client==${OPENPI_CLIENT_VERSION}" "msgpack==1.2.4"
        "websockets==17.4" "onnx==1.23.2" "onnxruntime==${ONNXRUNTIME_VERSION}"
        "protobuf==7.36.2"
        "scikit-learn==${SKLEARN_VERSION}" "scipy==1.17.1" "joblib==1.6.0" "threadpoolctl==3.8.0"
        "narwhals==2.29.0" "cloudpickle==3.1.3" "pillow==13.0.0")

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
    "$VPY" -c "import importlib.metadata as m; print(m.version('$1'))" 2>/dev/null || true
}

installed() {
    echo "mcap $(installed_version mcap), pymavlink $(installed_version pymavlink)," \
         "imageio-ffmpeg $(installed_version imageio-ffmpeg), pyarrow $(installed_version pyarrow)," \
         "openpi-client $(installed_version openpi-client), onnxruntime $(installed_version onnxruntime)," \
         "scikit-learn $(installed_version scikit-learn)"
}

WANTED="mcap ${MCAP_VERSION}, pymavlink ${PYMAVLINK_VERSION}, imageio-ffmpeg ${IMAGEIO_FFMPEG_VERSION}, pyarrow ${PYARROW_VERSION}, openpi-client ${OPENPI_CLIENT_VERSION}, onnxruntime ${ONNXRUNTIME_VERSION}, scikit-learn ${SKLEARN_VERSION}"
if [[ -x "$VPY" && "$(installed)" == "$WANTED" ]]; then
    say "venv $VENV already has $WANTED: nothing to do"
    echo "$VPY"
    exit 0
fi

if [[ ! -x "$VPY" ]]; then
    command -v "$PYTHON" >/dev/null 2>&1 || { say "'$PYTHON' not found: install Python 3 (apt-get install python3 python3-venv)"; exit 1; }
    say "creating venv $VENV with $("$PYTHON" --version 2>&1)"
    "$PYTHON" -m venv "$VENV" >&2 || { say "'$PYTHON -m venv' failed: on Debian install python3-venv"; exit 1; }
else
    say "venv $VENV exists but has $(installed), want $WANTED"
fi

say "installing ${PINNED[*]}"
"$VPY" -m pip install --quiet --disable-pip-version-check "${PINNED[@]}" >&2
say "done: $(installed)"
echo "$VPY"
