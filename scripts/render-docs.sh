#!/usr/bin/env bash
# Renders the camera images shown in the README (docs/images/) with `amstack render`:
# the EE, base and scene cameras of the FA-Hexa in three task scenes, the EE camera of every
# vehicle, all at reset with seed 0, and one scene with visual randomisation on.
#
#   bash scripts/render-docs.sh            # builds and runs amstack through cargo
#   AMSTACK=path/to/amstack bash scripts/render-docs.sh
#
# Needs a graphics adapter (scripts/setup.sh installs Mesa's Vulkan software rasteriser).
set -euo pipefail
cd "$(dirname "$0")/.."

out=docs/images
mkdir -p "$out"
if [[ -n "${AMSTACK:-}" ]]; then
    amstack=("$AMSTACK")
else
    cargo build --quiet --bin amstack
    amstack=(cargo run --quiet --bin amstack --)
fi

render() { "${amstack[@]}" render "$@"; }

for task in press-button peg-in-hole cabinet-pick-place; do
    for camera in ee base; do
        render --platform fa-hexa --task "$task" --camera "$camera" --out "$out/fa-hexa-$task-$camera.png"
    done
    # The scene camera at half the reference's 1280x720 keeps the PNGs small.
    render --platform fa-hexa --task "$task" --camera scene --scene-size 640x360 \
        --out "$out/fa-hexa-$task-scene.png"
done

for platform in ee-only ua-quad ua-hexa fa-hexa omni-hexa; do
    render --platform "$platform" --task press-button --camera ee --out "$out/$platform-ee-reset.png"
done

for seed in 1 2; do
    render --platform fa-hexa --task press-button --camera scene --scene-size 640x360 \
        --seed "$seed" --visual-dr on --out "$out/fa-hexa-press-button-scene-dr-$seed.png"
done
