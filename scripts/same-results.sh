#!/usr/bin/env bash
# Does a change keep every result? Runs the same flights with the build of BASE_REV and with the
# working tree's build, then compares results JSON (wall-clock figures dropped) and flight logs
# (MCAP messages byte for byte, read by the PyPI `mcap` package) with scripts/same_results.py.
#
#   bash scripts/same-results.sh BASE_REV [--keep DIR] [-- --ignore-field TOPIC:FIELD ...]
#
# AMSTACK_BASE_BIN=PATH uses a release binary of BASE_REV built earlier instead of building it.
#
# The flights (the one-loop refactor's contract, issue 15):
#   bench  FA-Hexa IK-PID and EE-only L1: press-button, toss-ball, wipe-window, 2 rollouts, seed 5,
#          reference disturbances, one MCAP per rollout
#   track  Omni-Hexa EE step with every disturbance (seed 3); FA-Hexa MPC EE step
#   replay of the Omni-Hexa track log
#   fly    over iceoryx2 (twin serve --ipc), and over MAVLink/UDP to the twin's autopilot at the
#          actuator and attitude levels, and a Push Slider task rollout at the actuator level
# Exit 1 when anything differs. Uses release builds; BASE_REV is built in a temporary worktree.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
base_rev=${1:?usage: same-results.sh BASE_REV [--keep DIR] [-- compare flags]}
shift
keep=""
compare_flags=()
while [ $# -gt 0 ]; do
    case "$1" in
        --keep) keep=$2; shift 2 ;;
        --) shift; compare_flags=("$@"); break ;;
        *) echo "same-results: unknown flag $1" >&2; exit 2 ;;
    esac
done

export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/amstack-target}"
out=${keep:-$(mktemp -d)}
mkdir -p "$out"
wt="$out/base-src"
cleanup() {
    git -C "$root" worktree remove --force "$wt" >/dev/null 2>&1 || true
    [ -n "$keep" ] || rm -rf "$out"
}
trap cleanup EXIT

if [ -n "${AMSTACK_BASE_BIN:-}" ]; then
    cp "$AMSTACK_BASE_BIN" "$out/amstack-base"   # a build of BASE_REV made earlier
else
    echo "same-results: building $base_rev" >&2
    git -C "$root" worktree remove --force "$wt" >/dev/null 2>&1 || true
    git -C "$root" worktree add --detach "$wt" "$base_rev" >/dev/null
    (cd "$wt" && cargo build --release --bin amstack >&2)
    cp "$CARGO_TARGET_DIR/release/amstack" "$out/amstack-base"
fi
echo "same-results: building the working tree" >&2
cargo build --release --bin amstack >&2
cp "$CARGO_TARGET_DIR/release/amstack" "$out/amstack-head"
py=$(bash scripts/setup-python.sh)

free_port() { python3 -c 'import socket; s=socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }

# Runs every flight with binary $1 in folder $2 (relative paths, so both folders hold the same names).
flights() {
    local bin=$1 dir=$2
    mkdir -p "$dir"
    cd "$dir"
    local tasks=press-button,toss-ball,wipe-window
    "$bin" bench --platform fa-hexa --task $tasks --rollouts 2 --seed 5 --disturbances reference \
        --out bench-fa --json bench-fa.json >/dev/null 2>&1
    "$bin" bench --platform ee-only --controller l1 --task $tasks --rollouts 2 --seed 5 \
        --disturbances reference --out bench-ee --json bench-ee.json >/dev/null 2>&1
    "$bin" track --platform omni-hexa --trajectory step --interface ee --disturbances all --seed 3 \
        --mcap track-omni.mcap --json track-omni.json >/dev/null 2>&1
    "$bin" track --platform fa-hexa --controller mpc --interface ee --trajectory step \
        --mcap track-mpc.mcap --json track-mpc.json >/dev/null 2>&1
    "$bin" replay track-omni.mcap --out replay-omni.mcap --json replay-omni.json >/dev/null 2>&1
    local twin=(--platform fa-hexa --disturbances saturation --seed 3)
    local svc="same-results-$$-$RANDOM"
    "$bin" twin serve --ipc "$svc" --sessions 1 "${twin[@]}" 2>/dev/null &
    local pid=$!
    "$bin" fly --link "ipc:$svc" "${twin[@]}" --trajectory step --duration 4 \
        --mcap fly-ipc.mcap --json fly-ipc.json >/dev/null 2>&1
    wait $pid || true
    local level
    for level in actuator attitude; do
        local port
        port=$(free_port)
        "$bin" twin serve --mavlink "udp:127.0.0.1:$port" --lockstep "${twin[@]}" 2>/dev/null &
        pid=$!
        sleep 0.5
        "$bin" fly --link "mavlink:udp:127.0.0.1:$port" --level $level "${twin[@]}" \
            --trajectory step --duration 4 --mcap "fly-mav-$level.mcap" \
            --json "fly-mav-$level.json" >/dev/null 2>&1
        kill -INT $pid 2>/dev/null || true
        wait $pid 2>/dev/null || true
    done
    port=$(free_port)
    "$bin" twin serve --mavlink "udp:127.0.0.1:$port" --lockstep "${twin[@]}" --task push-slider \
        2>/dev/null &
    pid=$!
    sleep 0.5
    "$bin" fly --link "mavlink:udp:127.0.0.1:$port" --level actuator "${twin[@]}" \
        --task push-slider --trajectory scripted --mcap fly-task.mcap --json fly-task.json \
        >/dev/null 2>&1
    kill -INT $pid 2>/dev/null || true
    wait $pid 2>/dev/null || true
    cd "$root"
}

echo "same-results: flying with the base build" >&2
flights "$out/amstack-base" "$out/base"
echo "same-results: flying with the working tree's build" >&2
flights "$out/amstack-head" "$out/head"
"$py" scripts/same_results.py "$out/base" "$out/head" "${compare_flags[@]}"
