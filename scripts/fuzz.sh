#!/usr/bin/env bash
# Mutation fuzzing of every decoder, the acquisition stream and the trace reader (stable
# Rust; fuzz/README.md). Usage: scripts/fuzz.sh [SECONDS_PER_TARGET] [magcomp-fuzz args...]
# CI (scripts/test.sh) runs 4 s per target; a longer local run: scripts/fuzz.sh 60
set -euo pipefail
cd "$(dirname "$0")/.."
secs=${1:-4}
shift || true
cargo build --release -q -p magcomp -p magcomp-fuzz
seeds=$(mktemp -d)
trap 'rm -rf "$seeds"' EXIT
# Seed captures and traces from the simulator (a short calibration flight, clean and with
# corrupted bytes), plus the shared NMEA logs when present.
target/release/magcomp simulate --flight calibration --seed 1 --manoeuvre-cycles 1 --level-s 5 \
    -o "$seeds/cal.csv" --capture "$seeds/cal.cap" >/dev/null
target/release/magcomp simulate --flight calibration --seed 2 --manoeuvre-cycles 1 --level-s 5 \
    -o "$seeds/cal2.csv" --capture "$seeds/corrupt.cap" --capture-corrupt 0.001 >/dev/null
corpus=(--corpus "$seeds")
[ -d data/reference/nmea ] && corpus+=(--corpus data/reference/nmea)
[ -f ../shared/reference-data/Flt1003_sample.xyz ] && corpus+=(--corpus ../shared/reference-data/Flt1003_sample.xyz)
target/release/magcomp-fuzz --seconds "$secs" "${corpus[@]}" "$@"
