#!/usr/bin/env bash
# Record -> train -> evaluate, end to end on this machine (docs/policies.md "Train here"):
#   1. `amstack record` writes demonstrations of a task's script (a LeRobot v3.0 dataset);
#   2. scripts/train_policy.py fits a behaviour-cloning MLP (scikit-learn) and exports ONNX + sidecar;
#   3. `amstack bench --policy onnx:MODEL` flies it in process (tract);
#   4. scripts/openpi_server.py serves the same model over openpi's protocol (onnxruntime) and
#      `amstack bench --policy remote:ws://127.0.0.1:PORT` flies it through the socket.
# Prints each step's command, and at the end success rates and query latencies of both paths;
# writes OUT/summary.json.
#
#   scripts/pipeline.sh [--out DIR] [--task ndt] [--platform fa-hexa] [--episodes 40]
#                       [--rollouts 30] [--eval-seed 1000] [--disturbances none] [--jobs N]
#
#   AMSTACK   the amstack binary (default: `amstack` on PATH, else target/release/amstack)
#
# NDT is the default task: its scene is not randomised, so a state-only policy sees all it needs.
# Press Button randomises the wall and the button (±0.2 m, ±0.3 m): a policy must see them
# (an image), which a state-only MLP does not.
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
out="runs/pipeline"; task="ndt"; platform="fa-hexa"; episodes=40; rollouts=30
eval_seed=1000; disturbances="none"; jobs=""
while [[ $# -gt 0 ]]; do
    case "$1" in
        --out) out="$2"; shift 2 ;;
        --task) task="$2"; shift 2 ;;
        --platform) platform="$2"; shift 2 ;;
        --episodes) episodes="$2"; shift 2 ;;
        --rollouts) rollouts="$2"; shift 2 ;;
        --eval-seed) eval_seed="$2"; shift 2 ;;
        --disturbances) disturbances="$2"; shift 2 ;;
        --jobs) jobs="--jobs $2"; shift 2 ;;
        -h|--help) sed -n '2,20p' "$0"; exit 0 ;;
        *) echo "pipeline.sh: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
done

amstack="${AMSTACK:-}"
if [[ -z "$amstack" ]]; then
    if command -v amstack >/dev/null 2>&1; then amstack="amstack";
    elif [[ -x "$here/../target/release/amstack" ]]; then amstack="$here/../target/release/amstack";
    else echo "pipeline.sh: no amstack binary: set AMSTACK=PATH (cargo build --release)" >&2; exit 2; fi
fi
py="$(bash "$here/setup-python.sh" | tail -n 1)"
if [[ -e "$out" && -n "$(ls -A "$out" 2>/dev/null)" ]]; then
    echo "pipeline.sh: --out $out is not empty" >&2; exit 2
fi
mkdir -p "$out"
run() { echo "+ $*" >&2; "$@"; }

run "$amstack" record --platform "$platform" --task "$task" --episodes "$episodes" --seed 0 $jobs \
    --out "$out/data" --json "$out/record.json"
run "$py" "$here/train_policy.py" "$out/data" --out "$out/policy.onnx" --json "$out/train.json"
run "$amstack" bench --platform "$platform" --task "$task" --rollouts "$rollouts" --seed "$eval_seed" \
    --disturbances "$disturbances" $jobs --policy "onnx:$out/policy.onnx" --json "$out/bench-onnx.json"

"$py" "$here/openpi_server.py" --port 0 --mode onnx --model "$out/policy.onnx" > "$out/server.out" 2> "$out/server.err" &
server=$!
trap 'kill "$server" 2>/dev/null || true' EXIT
url=""
for _ in $(seq 1 100); do
    url="$(sed -n 's/^listening on //p' "$out/server.out")"
    [[ -n "$url" ]] && break
    sleep 0.1
done
[[ -n "$url" ]] || { echo "pipeline.sh: the policy server did not start: $(cat "$out/server.err")" >&2; exit 1; }
run "$amstack" bench --platform "$platform" --task "$task" --rollouts "$rollouts" --seed "$eval_seed" \
    --disturbances "$disturbances" $jobs --policy "remote:$url" --json "$out/bench-remote.json"
kill "$server" 2>/dev/null || true

"$py" - "$out" "$task" <<'PY'
import json, sys
out, task = sys.argv[1], sys.argv[2]
load = lambda n: json.load(open(f"{out}/{n}.json"))
rec, train = load("record"), load("train")
summary = {"task": task, "record": {k: rec[k] for k in ("episodes_written", "frames_written", "dataset_bytes")},
           "record_wall_time_s": rec["timing"]["wall_time_s"],
           "train": {k: train[k] for k in ("samples", "epochs", "train_time_s", "validation_position_error_m")}}
for path in ("onnx", "remote"):
    b = load(f"bench-{path}")
    t = b["tasks"][task]
    summary[path] = {"success_rate": t["success_rate"], "rollouts": t["rollouts"], "policy_failed": t["policy_failed"],
                     "latency_ms_p50": b["policy"]["latency_ms"]["p50"], "latency_ms_p99": b["policy"]["latency_ms"]["p99"],
                     "queries": b["policy"]["queries"]}
    print(f"{path:>6}: success {100 * t['success_rate']:.1f} % of {t['rollouts']} rollouts, "
          f"{t['policy_failed']} policy_failed; query latency median {b['policy']['latency_ms']['p50']:.2f} ms, "
          f"p99 {b['policy']['latency_ms']['p99']:.2f} ms ({b['policy']['queries']} queries)")
json.dump(summary, open(f"{out}/summary.json", "w"), indent=2)
print(f"wrote {out}/summary.json")
PY
