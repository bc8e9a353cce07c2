#!/usr/bin/env bash
# Installs what amstack needs on a machine beyond a Rust toolchain. Idempotent; run by
# .ci/run. Today the workspace needs nothing else: every dependency builds from crates.io.
# Later pieces add their needs here (e.g. mesa-vulkan-drivers for wgpu's software adapter).
set -euo pipefail

need_cmd() {
    command -v "$1" >/dev/null 2>&1 || { echo "setup: '$1' not found: $2" >&2; exit 1; }
}
need_cmd cargo "install Rust (https://rustup.rs) first"
cargo fmt --version >/dev/null 2>&1 || { echo "setup: rustfmt missing: rustup component add rustfmt" >&2; exit 1; }
cargo clippy --version >/dev/null 2>&1 || { echo "setup: clippy missing: rustup component add clippy" >&2; exit 1; }
echo "setup: nothing to install"
