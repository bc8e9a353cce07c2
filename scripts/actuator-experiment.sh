#!/usr/bin/env bash
# The paper's actuator-dynamics experiment ("Actuator Dynamics Identification and Vertical
# Tracking"): the FA-Hexa flies the low- and high-frequency vertical sums of sines under
# four motor models, with rotor limits on. Prints a markdown table of base-z RMSE (cm) and
# the largest rotor thrust. Usage: scripts/actuator-experiment.sh [path/to/amstack]
set -euo pipefail
cd "$(dirname "$0")/.."
amstack=${1:-}
if [ -z "$amstack" ]; then
    cargo build --release --quiet
    amstack="${CARGO_TARGET_DIR:-target}/release/amstack"
fi
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

field() { python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(d[sys.argv[2]])" "$1" "$2"; }

echo "| Actuator configuration | Low-frequency RMSE (cm) | High-frequency RMSE (cm) | Max rotor thrust (N) |"
echo "|---|---|---|---|"
while IFS='|' read -r name flags; do
    row="| $name"
    peak=0
    for band in low high; do
        # shellcheck disable=SC2086
        "$amstack" track --platform fa-hexa --trajectory "sines-$band" --disturbances saturation $flags \
            --json "$tmp/$band.json" >/dev/null 2>&1
        rmse=$(field "$tmp/$band.json" base_z_rmse_m)
        row="$row | $(python3 -c "print(f'{$rmse * 100:.4f}')")"
        peak=$(python3 -c "print(max($peak, $(field "$tmp/$band.json" max_rotor_thrust_n)))")
    done
    echo "$row | $(python3 -c "print(f'{$peak:.2f}')") |"
done <<'ROWS'
No motor dynamics|
Motor delay (tau = 47.5 ms)|--motor-tau 0.0475
Rate limit (0.75 1/s)|--motor-rate-limit 0.75
Motor delay and rate limit|--motor-tau 0.0475 --motor-rate-limit 0.75
ROWS
