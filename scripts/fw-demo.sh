#!/bin/bash
# Firmware demo: a simulated flight's raw sensor capture streamed into the firmware running on
# the emulated board (QEMU STM32F405), its output port shown live by `magcomp monitor`, then
# the board's records compared with `magcomp replay` of the same capture.
# usage: scripts/fw-demo.sh [OUT_DIR]   (FW_DEMO_SPEED=1 for the sensors' real rates; default 4x)
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
cd "$ROOT"
OUT=${1:-demo-out}
SPEED=${FW_DEMO_SPEED:-4}
mkdir -p "$OUT"
bash scripts/install-qemu.sh >/dev/null
ELF=$(bash scripts/build-emu.sh 2>/dev/null | tail -1)
cargo build --release -q -p magcomp
cargo build -q -p hil-tests --bin hil-run
MAG=./target/release/magcomp
echo "== simulating a 2-minute calibration flight as raw sensor bytes ($OUT/fw-flight.cap)"
$MAG simulate --seed 3 --max-duration-s 120 --capture-gps-hz 1 \
  --capture "$OUT/fw-flight.cap" -o "$OUT/fw-flight.csv" >/dev/null
echo "== firmware on the emulated board, ${SPEED}x the sensors' rates; live output port:"
MAGCOMP_FW_ELF="$ELF" ./target/debug/hil-run "$OUT/fw-flight.cap" --speed "$SPEED" --out "$OUT/fw-board.csv" \
  | tee "$OUT/fw-board.txt" | $MAG monitor - --interval-s 2
echo "== the same capture through magcomp replay"
$MAG replay "$OUT/fw-flight.cap" --records "$OUT/fw-replay.txt" >/dev/null
if diff -q <(grep '^\$MCREC' "$OUT/fw-board.txt" | tr -d '\r') <(grep '^\$MCREC' "$OUT/fw-replay.txt" | tr -d '\r') >/dev/null; then
  echo "board records = magcomp replay records ($(grep -c '^\$MCREC' "$OUT/fw-board.txt") records, byte for byte)"
else
  echo "board and replay records differ: see $OUT/fw-board.txt and $OUT/fw-replay.txt"; exit 1
fi
