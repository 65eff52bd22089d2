#!/bin/bash
# Firmware CI: installs what it needs (Cortex-M4F target, QEMU 10, arm binutils), builds the
# real-board firmware (profile fw = release + LTO + opt-level s) and prints its flash/RAM,
# lints it, builds the emulated-board firmware and runs the hil-tests on QEMU, then the
# target benchmarks (MAGCOMP_SKIP_BENCH=1 skips them). About 4 min from a clean target dir
# on 2 cores, ~1.5 min incremental (the hil runs are ~45 s of real-time sensor streams).
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
cd "$ROOT"
t0=$(date +%s)
step() { echo; echo "== $* ($(( $(date +%s) - t0 )) s)"; }

step "install: target, QEMU 10, binutils-arm-none-eabi"
bash scripts/install-qemu.sh

step "real board (acq-f405): build"
cargo build --locked --profile fw --target thumbv7em-none-eabihf -p magcomp-firmware --bin magcomp-firmware
FW=target/thumbv7em-none-eabihf/fw/magcomp-firmware
arm-none-eabi-size "$FW"
arm-none-eabi-size "$FW" | awk 'NR==2{f=$1+$2; r=$2+$3;
  printf "flash %d B = %.1f KiB (budget 256 KiB), static RAM %d B = %.1f KiB (budget 64 KiB)\n", f, f/1024, r, r/1024;
  if (f > 262144 || r > 65536) { print "over budget"; exit 1 } }'

step "lint: firmware (acq, acq+flux-spi) and hil-tests"
cargo clippy --locked --no-deps -p magcomp-firmware --target thumbv7em-none-eabihf -- -D warnings
cargo clippy --locked --no-deps -p magcomp-firmware --target thumbv7em-none-eabihf --features flux-spi -- -D warnings
cargo clippy --locked --no-deps -p hil-tests --tests -- -D warnings
bash scripts/build-emu.sh --clippy >/dev/null

step "emulated board (emu-f405, QEMU netduinoplus2): build"
ELF=$(bash scripts/build-emu.sh | tail -1)
echo "$ELF"

step "host replay (magcomp replay: the board's records must equal it)"
# With magcomp-fuzz selected as scripts/fuzz.sh selects it: the same features of the shared
# dependencies (magcomp-fuzz turns on rand's small_rng), so after fuzz.sh in scripts/test.sh
# this is fresh instead of a second release build of the magcomp library.
cargo build --locked --release -p magcomp -p magcomp-fuzz --bin magcomp

step "hil-tests on QEMU"
MAGCOMP_BIN="$ROOT/target/release/magcomp" MAGCOMP_FW_ELF="$ELF" MAGCOMP_REQUIRE_QEMU=1 \
  cargo test --locked -p hil-tests -- --nocapture --test-threads=4

if [ "${MAGCOMP_SKIP_BENCH:-0}" != 1 ]; then
  step "target benchmarks"
  bash scripts/bench-target.sh
fi
step "firmware CI done"
