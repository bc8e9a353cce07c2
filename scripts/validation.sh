#!/usr/bin/env bash
# The paper's sim-to-real validation experiments ("Real-World Experiments" and appendix
# "Real-World Experiment Details"), re-flown in the twin with `amstack track`, `replay` and
# `compare`. A twin flight with the effect under study stands in for the physical flight.
#
#   bash scripts/validation.sh [OUT_DIR]        (default runs/validation)
#
#   AMSTACK   the amstack command (default: cargo run --release --quiet --)
#   PLOTS     where the PNGs go (default: OUT_DIR; the committed ones are in docs/validation)
#
# 1. Ground effect: the FA-Hexa flies the paper's ground sweep (EE z = 0.8 + 0.2 cos(2 pi t/30) m,
#    EE interface, IK-PID, 60 s) with the paper's evaluation disturbances and ground effect of
#    intensity rho = 3.4 (r_p = 0.152 m, the vehicle's propeller radius): the "real" flight.
#    It is replayed (reference mode: its logged EE targets through IK-PID) in the twin with and
#    without the ground-effect model, and each replay is compared with it over the two shaded
#    intervals of the paper, z_ref <= 0.7 m and z_ref >= 0.9 m.
# 2. Wrench-limit step responses: a 1 m x step (t = 1 s) with rotor limits, under two
#    wrench-space limits of the PID (I: |F| <= 80 N, II: |F| <= 100 N; hover needs 65 N), compared
#    with each other; which rotors saturate and when (scripts/rotor_saturation.py, read with
#    the independent PyPI mcap reader).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-runs/validation}"
PLOTS="${PLOTS:-$OUT}"
read -r -a AM <<< "${AMSTACK:-cargo run --release --quiet --}"
mkdir -p "$OUT" "$PLOTS"

echo "== ground effect (rho = 3.4, r_p = 0.152 m)"
"${AM[@]}" track --platform fa-hexa --trajectory ground-sweep --interface ee \
    --disturbances reference --ground-effect-k 3.4 --seed 0 \
    --mcap "$OUT/ge-real.mcap" --json "$OUT/ge-real.json"
"${AM[@]}" replay "$OUT/ge-real.mcap" --disturbances ground,saturation \
    --out "$OUT/ge-sim-with.mcap"
"${AM[@]}" replay "$OUT/ge-real.mcap" --disturbances saturation \
    --out "$OUT/ge-sim-without.mcap"
for which in with without; do
    echo "-- simulation $which the ground-effect model vs the 'real' flight"
    "${AM[@]}" compare "$OUT/ge-real.mcap" "$OUT/ge-sim-$which.mcap" \
        --signal /ee/pose.pose.position.z --signal /base/state.position_m[2] \
        --interval 'z_ref<=0.7' --interval 'z_ref>=0.9' \
        --json "$OUT/ge-compare-$which.json" --plot "$PLOTS/ground-effect-$which.png"
done

echo "== wrench-limit step responses"
for setting in "I 80" "II 100"; do
    read -r name force <<< "$setting"
    "${AM[@]}" track --platform fa-hexa --trajectory step --duration 6 --settle 0 \
        --disturbances saturation --max-force "$force" --seed 0 \
        --mcap "$OUT/step-$name.mcap" --json "$OUT/step-$name.json"
done
"${AM[@]}" compare "$OUT/step-I.mcap" "$OUT/step-II.mcap" \
    --signal /base/state.position_m[0] --signal /base/state.position_m[2] \
    --signal /control/wrench.force_n[0] --signal /control/wrench.force_n[2] \
    --signal /rotors.realised_n[1] --signal /rotors.realised_n[0] \
    --interval 't=1..3' --json "$OUT/step-compare.json" --plot "$PLOTS/wrench-limit-step.png"
PY="$(bash scripts/setup-python.sh | tail -n 1)"
"$PY" scripts/rotor_saturation.py "$OUT/step-I.mcap" "$OUT/step-II.mcap" --limits 0 23
