#!/usr/bin/env bash
# Opt-in end-to-end check of `amstack sweep --engine ray` (Ray is a ~200 MB install, so this is
# not part of `cargo test`): starts a local Ray cluster -- a head and one worker node, two
# process trees on 127.0.0.1 only (a network namespace of loopback only), one CPU each -- runs a sweep of 2 cells x 2 shards through
# it with one task's worker killed once (Ray must retry that shard), runs the same sweep with
# the local engine, and checks that every cell's results (less `timing`), config.json and
# MCAP logs are the same, byte for byte. Prints both wall times.
#
#   AMSTACK   the binary (default: $CARGO_TARGET_DIR/debug/amstack, else target/debug/amstack)
#   KEEP=1    keep the work folder
#
# Usage: bash scripts/ray-sweep-check.sh      (exit 0: equal; 1: a difference or a failure)
set -euo pipefail
cd "$(dirname "$0")/.."

# Ray 2.60 binds some of its ports on every interface even with --node-ip-address=127.0.0.1.
# To keep the cluster on 127.0.0.1 only, the whole check runs in a network namespace of its own
# whose only interface is the loopback (root, or unprivileged user namespaces, needed).
if [[ -z "${AMSTACK_RAY_NETNS:-}" ]]; then
    exec unshare --net --map-root-user env AMSTACK_RAY_NETNS=1 bash "$0" "$@"
fi
ip link set lo up

say() { echo "ray-sweep-check: $*" >&2; }

VPY="$(bash scripts/setup-ray.sh | tail -n 1)"
RAY="$(dirname "$VPY")/ray"
AMSTACK="${AMSTACK:-${CARGO_TARGET_DIR:-target}/debug/amstack}"
[[ -x "$AMSTACK" ]] || { say "no amstack binary at $AMSTACK: cargo build -p amstack"; exit 1; }
AMSTACK="$(realpath "$AMSTACK")"

WORK="$(mktemp -d /tmp/amstack-ray-check.XXXXXX)"
HEAD_PID=""; WORKER_PID=""
cleanup() {
    # Stop the two Ray process trees this script started, by their process groups.
    for pid in $WORKER_PID $HEAD_PID; do
        kill -TERM -- "-$pid" 2>/dev/null || true
    done
    sleep 2
    for pid in $WORKER_PID $HEAD_PID; do
        kill -KILL -- "-$pid" 2>/dev/null || true
    done
    [[ "${KEEP:-0}" == 1 ]] && say "kept $WORK" || rm -rf "$WORK"
}
trap cleanup EXIT

cat > "$WORK/sweep.toml" <<'TOML'
# 2 cells (the oracle under PID and under L1), 2 tasks x 2 rollouts each.
[[run]]
name = "pid"
platform = "ee-only"
controller = "pid"
task = "press-button,push-slider"
rollouts = 2
seed = 3

[[run]]
name = "l1"
platform = "ee-only"
controller = "l1"
task = "press-button,push-slider"
rollouts = 2
seed = 3
TOML

cd "$WORK"
PORT=$("$VPY" -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
export RAY_USAGE_STATS_ENABLED=0
say "starting the Ray head on 127.0.0.1:$PORT and one worker node (1 CPU each)"
setsid "$RAY" start --head --block --node-ip-address=127.0.0.1 --port="$PORT" --num-cpus=1 \
    --include-dashboard=false --temp-dir="$WORK/ray" >"$WORK/head.log" 2>&1 &
HEAD_PID=$!
for _ in $(seq 60); do
    grep -q "Ray runtime started" "$WORK/head.log" 2>/dev/null && break
    sleep 1
done
grep -q "Ray runtime started" "$WORK/head.log" || { say "the head did not start:"; tail "$WORK/head.log" >&2; exit 1; }
setsid "$RAY" start --block --address="127.0.0.1:$PORT" --node-ip-address=127.0.0.1 --num-cpus=1 \
    >"$WORK/worker.log" 2>&1 &
WORKER_PID=$!
for _ in $(seq 60); do
    grep -q "Ray runtime started" "$WORK/worker.log" 2>/dev/null && break
    sleep 1
done
grep -q "Ray runtime started" "$WORK/worker.log" || { say "the worker did not start:"; tail "$WORK/worker.log" >&2; exit 1; }

# The namespace has the loopback only, so whatever Ray listens on is reachable on 127.0.0.1 only.
LINKS="$(ip -o link show | awk -F': ' '{print $2}' | tr '\n' ' ')"
[[ "$LINKS" == "lo " ]] || { say "the namespace has other interfaces: $LINKS"; exit 1; }
PIDS="$(pgrep -d'|' -g "$HEAD_PID,$WORKER_PID" || true)"
LISTEN="$(ss -ltnpH 2>/dev/null | grep -E "pid=($PIDS)," | awk '{print $4}' | sort -u | wc -l)"
say "network namespace with interfaces: $LINKS; the cluster listens on $LISTEN TCP ports there"
say "sweep through Ray (2 cells x 2 shards; the first attempt of pid:1 kills its worker)"
T0=$(date +%s.%N)
"$AMSTACK" sweep sweep.toml --out out --engine "ray:127.0.0.1:$PORT" --shards 2 \
    --ray-python "$VPY" --kill-once pid:1
T1=$(date +%s.%N)
mv out ray-out
say "the same sweep with the local engine"
"$AMSTACK" sweep sweep.toml --out out
T2=$(date +%s.%N)

"$VPY" - ray-out out <<'PY'
import filecmp, json, os, sys
ray_dir, local_dir = sys.argv[1], sys.argv[2]
bad = 0
for cell in ("pid", "l1"):
    a = json.load(open(f"{ray_dir}/cells/{cell}/results.json"))
    b = json.load(open(f"{local_dir}/cells/{cell}/results.json"))
    a.pop("timing"); b.pop("timing")
    if json.dumps(a).replace(ray_dir + "/", local_dir + "/") != json.dumps(b):
        print(f"cell {cell}: results differ"); bad += 1
    files = sorted(os.path.relpath(os.path.join(r, n), f"{local_dir}/cells/{cell}")
                   for r, _, ns in os.walk(f"{local_dir}/cells/{cell}") for n in ns)
    files_ray = sorted(os.path.relpath(os.path.join(r, n), f"{ray_dir}/cells/{cell}")
                       for r, _, ns in os.walk(f"{ray_dir}/cells/{cell}") for n in ns)
    if files != files_ray:
        print(f"cell {cell}: files differ: {files} vs {files_ray}"); bad += 1
    for f in files:
        if f != "results.json" and not filecmp.cmp(f"{ray_dir}/cells/{cell}/{f}",
                                                   f"{local_dir}/cells/{cell}/{f}", shallow=False):
            print(f"cell {cell}: {f} differs"); bad += 1
    print(f"cell {cell}: {len(files) - 1} files compared byte for byte, results equal" if not bad else "")
sys.exit(1 if bad else 0)
PY
echo "kill-once: $(cat ray-out/kill-once.done)"
"$VPY" -c "print(f'wall time: Ray (2 nodes x 1 CPU, 2 shards per cell) {$T1 - $T0:.1f} s; local engine {$T2 - $T1:.1f} s')"
say "OK: the Ray sweep equals the local one"
