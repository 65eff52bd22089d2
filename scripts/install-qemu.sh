#!/bin/bash
# Idempotent: installs QEMU 10 (qemu-system-arm from bookworm-backports), the Cortex-M4F
# Rust target and binutils-arm-none-eabi (sizes, nm for the benchmark markers).
# No mirror address is written anywhere: the backports stanza is derived from the machine's
# own /etc/apt/sources.list.d/debian.sources in a private directory; /etc is not touched.
set -euo pipefail
SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
need_qemu=1
if command -v qemu-system-arm >/dev/null; then
  v=$(qemu-system-arm --version | sed -n 's/.*version \([0-9]*\)\..*/\1/p' | head -1)
  [ "${v:-0}" -ge 10 ] && need_qemu=0
fi
need_bin=0; command -v arm-none-eabi-nm >/dev/null || need_bin=1
if [ $need_qemu = 1 ] || [ $need_bin = 1 ]; then
  SRC_DIR=${MAGCOMP_APT_DIR:-/tmp/magcomp-apt-sources}
  mkdir -p "$SRC_DIR"
  base=/etc/apt/sources.list.d/debian.sources
  cp "$base" "$SRC_DIR/debian.sources"
  # first stanza (up to the first blank line), with the suite replaced
  awk 'BEGIN{RS=""; ORS="\n\n"} NR==1{print; exit}' "$base" \
    | sed 's/^Suites:.*/Suites: bookworm-backports/' > "$SRC_DIR/backports.sources"
  APT=(-o Dir::Etc::SourceParts="$SRC_DIR" -o Dir::Etc::SourceList=/dev/null)
  $SUDO apt-get "${APT[@]}" update -qq
  pk=()
  [ $need_bin = 1 ] && pk+=(binutils-arm-none-eabi)
  [ ${#pk[@]} -gt 0 ] && DEBIAN_FRONTEND=noninteractive $SUDO apt-get "${APT[@]}" install -y -qq "${pk[@]}"
  [ $need_qemu = 1 ] && DEBIAN_FRONTEND=noninteractive $SUDO apt-get "${APT[@]}" install -y -qq \
      -t bookworm-backports --no-install-recommends qemu-system-arm
fi
rustup target list --installed | grep -q thumbv7em-none-eabihf || rustup target add thumbv7em-none-eabihf
qemu-system-arm --version | head -1
