#!/usr/bin/env bash
# Installs what amstack needs on a machine beyond a Rust toolchain. Idempotent; run by
# .ci/run (as root in CI). Every Rust dependency builds from crates.io; at run time the
# renderer (crate `render`, wgpu) needs a graphics adapter: on a machine without a GPU that is
# Mesa's Vulkan software rasteriser (llvmpipe, Debian package `mesa-vulkan-drivers`).
set -euo pipefail

need_cmd() {
    command -v "$1" >/dev/null 2>&1 || { echo "setup: '$1' not found: $2" >&2; exit 1; }
}
need_cmd cargo "install Rust (https://rustup.rs) first"
cargo fmt --version >/dev/null 2>&1 || { echo "setup: rustfmt missing: rustup component add rustfmt" >&2; exit 1; }
cargo clippy --version >/dev/null 2>&1 || { echo "setup: clippy missing: rustup component add clippy" >&2; exit 1; }

# Debian packages the workspace needs at run time (not to compile).
debian_packages=(mesa-vulkan-drivers)

missing=()
if command -v dpkg-query >/dev/null 2>&1; then
    for pkg in "${debian_packages[@]}"; do
        status=$(dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null || true)
        [[ "$status" == "install ok installed" ]] || missing+=("$pkg")
    done
else
    echo "setup: not a Debian-like system (no dpkg-query): install ${debian_packages[*]} (or your" \
        "distribution's Mesa Vulkan drivers) yourself for the renderer" >&2
fi

if ((${#missing[@]} == 0)); then
    echo "setup: nothing to install"
    exit 0
fi

if [[ $(id -u) -eq 0 ]]; then
    as_root=()
elif command -v sudo >/dev/null 2>&1; then
    as_root=(sudo)
else
    echo "setup: missing ${missing[*]} and not root (no sudo): run 'apt-get install ${missing[*]}' as root" >&2
    exit 1
fi

echo "setup: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
"${as_root[@]}" apt-get update -qq
"${as_root[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
echo "setup: installed ${missing[*]}"
