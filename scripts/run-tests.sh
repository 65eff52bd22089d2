#!/usr/bin/env bash
# Runs the host's test binaries two at a time (release build).
#
# Why not plain `cargo test`: cargo runs its test binaries one after another, and the slow
# ones loop over simulated flights inside a few tests, so on CI's 2 cores a third of the
# test time ran on one core. Each binary's output is printed whole once it ends, in the
# order they finish; the script fails if any binary failed, after running all of them.
# Usage: scripts/run-tests.sh [JOBS]   (default 2)
set -euo pipefail
cd "$(dirname "$0")/.."
jobs=${1:-2}
packages=(-p magcomp-core -p magcomp)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# One line per test executable: "<package dir> <executable>", from cargo's build messages.
cargo test --release "${packages[@]}" --no-run --message-format=json-render-diagnostics \
    >"$work/build.json"
grep '"profile":{[^}]*"test":true' "$work/build.json" | grep '"executable":"' |
    sed -E 's/.*"manifest_path":"([^"]*)\/Cargo.toml".*"executable":"([^"]*)".*/\1 \2/' \
        >"$work/binaries"

# The slowest binaries first (measured on CI), so none of them starts last and runs alone.
slow_first="diagnose_effects diagnose_iterate glitch_sweep lag_delay report_flight"
{
    for name in $slow_first; do grep "/${name}-[0-9a-f]*\$" "$work/binaries" || true; done
    for name in $slow_first; do printf '/%s-[0-9a-f]*$\n' "$name"; done >"$work/slow.pat"
    grep -v -f "$work/slow.pat" "$work/binaries"
} >"$work/ordered"
count=$(wc -l <"$work/ordered")
[ "$count" -gt 0 ] || { echo "no test binaries found" >&2; exit 1; }

run_one() {
    local dir=$1 exe=$2 work=$3 name log
    name=$(basename "$exe")
    log="$work/${name}.log"
    if (cd "$dir" && "$exe") >"$log" 2>&1; then status=ok; else status=FAILED; fi
    { printf '\n     Running %s (%s) %s\n' "${exe#"$PWD"/}" "$dir" "$status"; cat "$log"; } |
        flock "$work/print.lock" cat
    [ "$status" = ok ] || touch "$work/failed.$name"
}
export -f run_one

echo "running $count test binaries, $jobs at a time"
xargs -P "$jobs" -L 1 bash -c 'run_one "$0" "$1" "'"$work"'"' <"$work/ordered"

cargo test --release "${packages[@]}" --doc

failed=$(find "$work" -maxdepth 1 -name 'failed.*' -printf '%f\n' | sed 's/^failed\.//')
if [ -n "$failed" ]; then
    echo "test binaries that failed:" >&2
    echo "$failed" >&2
    exit 1
fi
echo "all $count test binaries passed"
