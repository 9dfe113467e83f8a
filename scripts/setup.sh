#!/usr/bin/env bash
# Installs what building and testing need on a fresh Debian machine with rustup's toolchain.
# Idempotent: does nothing that is already in place.
set -euo pipefail
if ! command -v cargo >/dev/null 2>&1; then
    echo "setup: cargo is missing; install the Rust toolchain (https://rustup.rs) first" >&2
    exit 1
fi
# The scene tests read ../shared/scenes; say so early rather than failing deep in a test.
here="$(cd "$(dirname "$0")/.." && pwd)"
shared="${MLT_SHARED:-$here/../shared}"
if [ ! -d "$shared/scenes" ]; then
    echo "setup: warning: $shared/scenes not found; tests that read the shared scenes will fail (set MLT_SHARED)" >&2
fi
# No system packages are needed yet: the bake is pure Rust (the viewer issue will add
# mesa-vulkan-drivers and libvulkan1 here).
cargo fetch --locked
