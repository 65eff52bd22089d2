#!/usr/bin/env bash
# Runs every test of the project on a fresh machine: installs what it needs (Rust target,
# QEMU 10, Chromium, ARM binutils), checks formatting and lints on host and target,
# runs the host tests, builds the board firmware and runs the firmware in QEMU (hil-tests).
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TERM_COLOR=${CARGO_TERM_COLOR:-never}

step() { printf '\n=== %s ===\n' "$*"; }

step "toolchain and system packages"
scripts/install-deps.sh

step "format"
cargo fmt --all -- --check

step "clippy (host)"
cargo clippy -p magcomp-core -p magcomp -p magcomp-fuzz --all-targets -- -D warnings

step "core builds for the board (no_std, thumbv7em-none-eabihf)"
cargo build -p magcomp-core --target thumbv7em-none-eabihf --release

step "host tests (release: the accuracy tests fly whole simulated flights; two binaries at a time)"
scripts/run-tests.sh

step "fuzz: every decoder, the acquisition stream, the trace reader (4 s per target)"
scripts/fuzz.sh 4

if [ -x scripts/fw-ci.sh ]; then
    step "firmware: build, size, QEMU hil-tests"
    MAGCOMP_REQUIRE_QEMU=${MAGCOMP_REQUIRE_QEMU:-1} scripts/fw-ci.sh
fi

step "benchmarks compile"
# The packages of scripts/run-tests.sh: the same features of the shared dependencies (the
# core's dev-dependencies add some), so the library and its dependencies built for the tests
# are reused (`cargo test --release` builds with the bench profile) and only the benchmarks
# compile.
cargo bench -p magcomp-core -p magcomp --no-run

echo
echo "all checks passed"
