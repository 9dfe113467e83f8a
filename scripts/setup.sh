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
# The viewer renders with wgpu on Vulkan. Without a GPU, Mesa's software driver (lavapipe)
# serves, headless and under Xvfb; the window tests need xvfb. The check of the Kubernetes
# manifests (scripts/farm/k8s/check.sh) reads them with Python's yaml and fills them with
# envsubst. Installed only when missing.
need=()
for pkg in mesa-vulkan-drivers libvulkan1 xvfb xauth python3-yaml gettext-base; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || need+=("$pkg")
done
if [ ${#need[@]} -gt 0 ]; then
    if ! command -v apt-get >/dev/null 2>&1; then
        echo "setup: please install ${need[*]} (or your system's Vulkan driver and loader)" >&2
        exit 1
    fi
    sudo_cmd=()
    [ "$(id -u)" -ne 0 ] && sudo_cmd=(sudo)
    echo "setup: installing ${need[*]}" >&2
    "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${need[@]}" >/dev/null \
        || { "${sudo_cmd[@]}" apt-get update -q >/dev/null && "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${need[@]}" >/dev/null; }
fi
cargo fetch --locked
