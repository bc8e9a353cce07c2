#!/usr/bin/env bash
# Fidelity of fewer physics substeps per 120 Hz control tick (docs/speed.md): the same flights
# with --physics-substeps 1, 2 and 4 (the default), compared by scripts/substep_study.py.
#
#   bash scripts/substep-study.sh [OUT_DIR] [ROLLOUTS]     (default runs/substeps, 5)
#
#   AMSTACK   the amstack command (default: cargo run --release --quiet --)
#   SUBSTEPS  the counts to fly (default "1 2 4")
#   TASKS     the benchmark tasks (default push-slider,press-button,wipe-window,cabinet-pick-place)
#
# Flights per count: FA-Hexa hover 20 s and x step with the reference disturbances (base
# tracking), an EE step (EE interface), the Omni-Hexa EE step with every disturbance, and the
# benchmark on TASKS (FA-Hexa, IK-PID, reference disturbances, seed 0). Each flight's wall
# time is kept, so the table shows the speed each count buys.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-runs/substeps}"
ROLLOUTS="${2:-5}"
read -r -a AM <<< "${AMSTACK:-cargo run --release --quiet --}"
TASKS="${TASKS:-push-slider,press-button,wipe-window,cabinet-pick-place}"
mkdir -p "$OUT"
for n in ${SUBSTEPS:-1 2 4}; do
    echo "== $n physics substep(s) per tick" >&2
    d="$OUT/n$n"
    mkdir -p "$d"
    timed() { # NAME ARGS...: runs amstack, keeps its wall time in NAME.time
        local name=$1
        shift
        local start end
        start=$(date +%s.%N)
        "${AM[@]}" "$@" --physics-substeps "$n" >"$d/$name.log" 2>&1
        end=$(date +%s.%N)
        echo "$end - $start" | bc >"$d/$name.time"
    }
    timed hover track --platform fa-hexa --trajectory hover --duration 20 \
        --disturbances reference --json "$d/hover.json"
    timed step track --platform fa-hexa --trajectory step --disturbances reference \
        --json "$d/step.json"
    timed ee-step track --platform fa-hexa --trajectory step --interface ee \
        --disturbances reference --json "$d/ee-step.json"
    timed omni track --platform omni-hexa --trajectory step --interface ee --disturbances all \
        --seed 3 --json "$d/omni.json"
    timed bench bench --platform fa-hexa --task "$TASKS" --rollouts "$ROLLOUTS" --jobs 1 \
        --disturbances reference --seed 0 --out "$d/bench" --json "$d/bench.json"
done
python3 scripts/substep_study.py "$OUT"
