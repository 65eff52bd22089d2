#!/usr/bin/env bash
# The sweep behind the README's "unmodelled scalar lag" row (issue 20): broad simulated
# calibrations, seeds 1–6, a hidden scalar delay of 0, 0.05, 0.1 and 0.25 s among two decoy
# channels. For each: what `diagnose` names (and the evidence it rests on), the error
# against truth of the Kalman calibration without the named term and with it.
# Usage: scripts/lag-sweep.sh [OUT_DIR]   (about 5 minutes on 2 cores)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-target/lag-sweep}
mkdir -p "$out"
cargo build --release -q -p magcomp
mc=target/release/magcomp
err() { python3 -c "import json,sys; print('%.4f' % json.load(sys.stdin)['error_rms_nt'])"; }
for seed in 1 2 3 4 5 6; do
  for tau in 0 0.05 0.1 0.25; do
    f=$out/s${seed}_t${tau}.csv
    hidden=()
    [ "$tau" != 0 ] && hidden=(--hidden "lag:$tau")
    $mc simulate --physics broad --seed "$seed" "${hidden[@]}" \
      --decoy cur_pump --decoy temp_bay -o "$f" >/dev/null 2>&1
    named=$($mc diagnose "$f" --json | python3 -c "
import json, sys
d = json.load(sys.stdin)
c = [c for c in d['candidates'] if c['significant']]
print(c[0]['term'] + '[' + '+'.join(c[0]['evidence']) + ']' if c else '-')")
    base=$($mc compensate "$f" -o "$out/o.csv" --json --model tl16+field+fluxcal --method kf 2>/dev/null | err)
    term=${named%%[*}
    with=-
    if [ "$term" != - ]; then
      with=$($mc compensate "$f" -o "$out/o.csv" --json --model "tl16+field+fluxcal+$term" --method kf 2>/dev/null | err)
    fi
    echo "seed $seed τ $tau s: named $named; error $base → $with nT"
  done
done
