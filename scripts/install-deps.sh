#!/usr/bin/env bash
# Installs what the build and tests need; idempotent, quiet when everything is there.
set -euo pipefail
if ! rustup target list --installed 2>/dev/null | grep -q thumbv7em-none-eabihf; then
    rustup target add thumbv7em-none-eabihf
fi
rustup component list --installed 2>/dev/null | grep -q '^clippy' || rustup component add clippy
rustup component list --installed 2>/dev/null | grep -q '^rustfmt' || rustup component add rustfmt
need=()
command -v chromium >/dev/null || need+=(chromium)
command -v arm-none-eabi-size >/dev/null || need+=(binutils-arm-none-eabi)
# libhdf5 for `.h5` traces (hdf5-metno finds Debian's /usr/lib/*/hdf5/serial via pkg-config)
pkg-config --exists hdf5 2>/dev/null || need+=(libhdf5-dev pkg-config)
if [ ${#need[@]} -gt 0 ]; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO=sudo
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need[@]}" >/dev/null
fi
if [ -x "$(dirname "$0")/install-qemu.sh" ]; then
    "$(dirname "$0")/install-qemu.sh"
fi
