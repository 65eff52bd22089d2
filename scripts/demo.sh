#!/usr/bin/env bash
# The main job, end to end on built-in simulated data: simulate a calibration and a survey
# flight, calibrate, compensate (Kalman filter and Tolles–Lawson side by side against the
# simulator's truth), find a hidden physical effect and remove it, and run the firmware
# on the emulated board against a simulated flight.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
cargo build --release -q -p magcomp
OUT=${OUT:-demo-out}
./target/release/magcomp demo --out "$OUT"
if [ -x scripts/fw-demo.sh ]; then
    scripts/fw-demo.sh "$OUT"
fi
