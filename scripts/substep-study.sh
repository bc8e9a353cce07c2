#!/usr/bin/env bash
# Fidelity of cheaper twin physics (docs/speed.md): the same flights at each (P, I) pair of
# physics substeps per 120 Hz tick (--physics-substeps P) and solver iterations per substep
# (--solver-iterations I), compared with 4x4 by scripts/substep_study.py. A pair PxI splits
# rapier's solver into I steps of one constraint pass (--rapier-steps I: the split before
# that flag existed); PxIsS into S steps sharing the I passes (--rapier-steps S; the default
# is 4x4s1). rapier rebuilds the vehicle's mass matrix at each of its solver steps.
#
#   bash scripts/substep-study.sh [OUT_DIR] [ROLLOUTS]     (default runs/substeps, 5)
#
#   AMSTACK      the amstack command (default: cargo run --release --quiet --)
#   PAIRS        the PxI[sS] pairs to fly (default "4x4 1x4 4x1 2x2 2x1 1x2 1x1")
#   BENCH_PAIRS  the pairs that also run the benchmark (default: all of PAIRS; "" for none)
#   TASKS        the benchmark tasks (default all)
#   EXPERIMENTS  1 (default) to run `experiment actuator|ground-effect|wrench-limit` per pair
#   JOBS         worker threads of the benchmark and the experiments (default 1)
#
# Flights per pair: FA-Hexa hover 20 s and x step with the reference disturbances (base
# tracking), an EE step (EE interface), the Omni-Hexa EE step with every disturbance, the
# validation experiments, and the benchmark on TASKS (FA-Hexa, IK-PID, reference
# disturbances, seed 0; its MCAPs hold the grasped objects' trajectories). A pair's folder
# that already holds a result is kept (re-run the study to fill in what is missing).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-runs/substeps}"
ROLLOUTS="${2:-5}"
read -r -a AM <<< "${AMSTACK:-cargo run --release --quiet --}"
PAIRS="${PAIRS:-4x4 1x4 4x1 2x2 2x1 1x2 1x1}"
BENCH_PAIRS="${BENCH_PAIRS-$PAIRS}"
TASKS="${TASKS:-all}"
JOBS="${JOBS:-1}"
mkdir -p "$OUT"
for pair in $PAIRS; do
    p=${pair%%x*}
    rest=${pair#*x}
    i=${rest%%s*}
    if [[ "$rest" == *s* ]]; then
        s=${rest#*s}
        d="$OUT/p${p}i${i}s${s}"
    else
        s=$i
        d="$OUT/p${p}i${i}"
    fi
    mkdir -p "$d"
    echo "== $p physics substep(s) x $i solver iteration(s) per tick, $s rapier step(s) -> $d" >&2
    timed() { # NAME ARGS...: runs amstack at this pair unless NAME is done, keeps its wall time
        local name=$1
        shift
        [[ -s "$d/$name.time" ]] && return 0
        local start end
        start=$(date +%s.%N)
        "${AM[@]}" "$@" --physics-substeps "$p" --solver-iterations "$i" --rapier-steps "$s" \
            >"$d/$name.log" 2>&1
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
    if [[ "${EXPERIMENTS:-1}" == 1 ]]; then
        for e in actuator ground-effect wrench-limit; do
            [[ -s "$d/$e.time" ]] || rm -rf "$d/exp-$e"
            timed "$e" experiment "$e" --jobs "$JOBS" --out "$d/exp-$e"
        done
    fi
    if [[ " $BENCH_PAIRS " == *" $pair "* ]]; then
        [[ -s "$d/bench.time" ]] || rm -rf "$d/bench"
        timed bench bench --platform fa-hexa --task "$TASKS" --rollouts "$ROLLOUTS" \
            --jobs "$JOBS" --disturbances reference --seed 0 --out "$d/bench" --json "$d/bench.json"
    fi
done
"${PYTHON:-python3}" scripts/substep_study.py "$OUT"
