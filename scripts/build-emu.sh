#!/bin/bash
# Builds the firmware for the emulated board (QEMU netduinoplus2, STM32F405) and prints the
# ELF path on the last line of stdout.
#
# The emulated build uses a patched copy of embassy-stm32 0.6.0 (every change behind
# cfg(embassy_qemu), see hil-tests/qemu/make-qemu-embassy-stm32.sh) selected through a
# generated --config file with [patch.crates-io]. It has its own target dir (target/emu),
# so it never invalidates the real-board build, and Cargo.lock is restored afterwards
# because the [patch] rewrites embassy-stm32's source line (keep it out of --locked builds).
# usage: scripts/build-emu.sh [extra cargo args, e.g. --bin kf_bench --features bench]
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
cd "$ROOT"
EMU="$ROOT/target/emu"
PATCHED="$EMU/embassy-stm32-qemu"
mkdir -p "$EMU"
STAMP="$PATCHED/.magcomp-patched"
if [ ! -f "$STAMP" ] || [ "$ROOT/hil-tests/qemu/make-qemu-embassy-stm32.sh" -nt "$STAMP" ]; then
  cargo fetch -q >&2   # the registry copy of embassy-stm32 the patch starts from
  bash "$ROOT/hil-tests/qemu/make-qemu-embassy-stm32.sh" "$PATCHED" >/dev/null
  touch "$STAMP"
fi
CFG="$EMU/cargo-emu.toml"
cat > "$CFG" <<TOML
[patch.crates-io]
embassy-stm32 = { path = "$PATCHED" }
[target.thumbv7em-none-eabihf]
rustflags = ["--cfg", "embassy_qemu"]
TOML
cp Cargo.lock "$EMU/Cargo.lock.orig"
restore() { cp "$EMU/Cargo.lock.orig" Cargo.lock; }
trap restore EXIT
cargo build --config "$CFG" --target-dir "$EMU" --profile fw --target thumbv7em-none-eabihf \
  -p magcomp-firmware --no-default-features --features board-emu "$@" >&2
BIN=magcomp-firmware
prev=""
for a in "$@"; do [ "$prev" = "--bin" ] && BIN=$a; prev=$a; done
echo "$EMU/thumbv7em-none-eabihf/fw/$BIN"
