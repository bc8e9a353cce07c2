#!/usr/bin/env bash
# Split-process SITL benchmark: the same flight in-process and against `amstack twin serve`
# in lockstep over iceoryx2, with the per-tick round trip over the wire.
#
#   bash scripts/sitl-bench.sh [amstack flags...]     (default: FA-Hexa, PID, sines-high, 60 s)
#
# Prints ticks per second both ways and the round trip's median, p99 and p99.9 (and the
# transport alone: round trip minus the twin's own stepping). Uses the release build.
set -euo pipefail
cd "$(dirname "$0")/.."

export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/amstack-target}"
cargo build --release --bin amstack >&2
bin="$CARGO_TARGET_DIR/release/amstack"

flags=("$@")
if [ ${#flags[@]} -eq 0 ]; then
    flags=(--platform fa-hexa --trajectory sines-high --duration 60 --disturbances reference)
fi
# The twin takes the flags that describe it.
twin_flags=()
for ((i = 0; i < ${#flags[@]}; i++)); do
    case "${flags[i]}" in
        --platform|--disturbances|--seed|--motor-tau|--motor-rate-limit|--ground-effect-k|--vehicle)
            twin_flags+=("${flags[i]}" "${flags[i+1]}"); i=$((i + 1)) ;;
    esac
done

out="$(mktemp -d)"
service="bench-$$"
"$bin" twin serve --ipc "$service" --sessions 1 "${twin_flags[@]}" 2>"$out/twin.log" &
twin=$!
trap 'kill -INT $twin 2>/dev/null || true; wait $twin 2>/dev/null || true; rm -rf "$out"' EXIT

"$bin" track "${flags[@]}" --json "$out/in.json" >/dev/null 2>&1
"$bin" fly --link "ipc:$service" "${flags[@]}" --json "$out/ipc.json" \
    --timing-json "$out/timing.json" >/dev/null 2>"$out/fly.log" || { cat "$out/fly.log" >&2; exit 1; }

python3 - "$out" "${flags[*]}" <<'EOF'
import json, sys
out, flags = sys.argv[1], sys.argv[2]
inproc = json.load(open(f"{out}/in.json"))
ipc = json.load(open(f"{out}/ipc.json"))
t = json.load(open(f"{out}/timing.json"))
same = {k: v for k, v in inproc.items() if k not in ("wall_time_s", "ticks_per_second", "mcap")} == \
       {k: v for k, v in ipc.items() if k not in ("wall_time_s", "ticks_per_second", "mcap")}
print(f"scenario: {flags}  ({t['ticks']} ticks)")
print(f"| | ticks/s |")
print(f"|---|---|")
print(f"| in-process twin | {inproc['ticks_per_second']:.0f} |")
print(f"| twin process, lockstep over iceoryx2 | {ipc['ticks_per_second']:.0f} |")
print(f"results JSON identical: {same}")
print()
print("| per tick, µs | median | p99 | p99.9 | max |")
print("|---|---|---|---|---|")
for name, key in [("round trip (command → measurement)", "round_trip"),
                  ("twin stepping (reported by the twin)", "twin_busy"),
                  ("transport (round trip − stepping)", "transport")]:
    p = t[key]
    print(f"| {name} | {p['median_us']:.1f} | {p['p99_us']:.1f} | {p['p99_9_us']:.1f} | {p['max_us']:.1f} |")
EOF
