#!/usr/bin/env bash
# Peak memory (RSS) and wall time of the commands that calibrate — `calibrate`,
# post-flight `compensate` (no --coeffs) and `diagnose` — on a simulated 1 kHz calibration
# flight (seed 8, 708,421 rows) repeated with its time shifted to the wanted row count.
# Above 2 M rows they calibrate on a copy decimated to 100 Hz (docs/streaming.md).
# A measurement, not a test. Needs GNU /usr/bin/time. Usage:
#   scripts/calibrate_rss.sh                                  # 1,000,000 and 10,000,000 rows
#   ROWS="1000000" FLAGS="--decimate-above-rows 0" scripts/calibrate_rss.sh
#   COMMANDS="calibrate" FLAGS="--full-rate" scripts/calibrate_rss.sh
# Env: ROWS (comma-separated), COMMANDS (default "calibrate compensate diagnose"), FLAGS
# (added to every command), DIR (default $TMPDIR/magcomp-calibrate-rss; ~360 B of disk
# per row).
set -euo pipefail
cd "$(dirname "$0")/.."
nice -n 10 cargo build --release -p magcomp --bin magcomp >&2
bin="$PWD/target/release/magcomp"
dir="${DIR:-${TMPDIR:-/tmp}/magcomp-calibrate-rss}"
mkdir -p "$dir"
cd "$dir"
[ -f base.csv ] || nice -n 10 "$bin" simulate --flight calibration --seed 8 --rate-hz 1000 -o base.csv >&2
printf '%-10s %-11s %12s %12s %10s  %s\n' rows command "peak MiB" "B/row" wall note
IFS=',' read -ra counts <<< "${ROWS:-1000000,10000000}"
for n in "${counts[@]}"; do
    f="cal_$n.csv"
    if [ ! -f "$f" ]; then
        # The base flight's data rows repeated, t (first column) shifted by its span.
        nice -n 10 awk -v N="$n" -F, -v OFS=, '
            /^#/ { head[nh++] = $0; next }
            hdr == "" { hdr = $0; next }
            { k++; t[k] = $1; sub(/^[^,]*,/, ""); rest[k] = $0 }
            END {
                for (i = 0; i < nh; i++) print head[i]; print hdr
                span = t[k] - t[1] + (t[2] - t[1])
                for (rep = 0; ; rep++) for (i = 1; i <= k; i++) {
                    if (m == N) exit
                    printf "%.4f,%s\n", t[i] + rep * span, rest[i]; m++
                }
            }' base.csv > "$f"
    fi
    for cmd in ${COMMANDS:-calibrate compensate diagnose}; do
        case $cmd in
            calibrate) args=(calibrate "$f" -o coeffs.json) ;;
            compensate) args=(compensate "$f" -o out.csv) ;;
            diagnose) args=(diagnose "$f") ;;
        esac
        # shellcheck disable=SC2086
        /usr/bin/time -v "$bin" "${args[@]}" ${FLAGS:-} > "run_$cmd.out" 2> "run_$cmd.err" || {
            echo "$cmd failed:" >&2; tail -5 "run_$cmd.err" >&2; exit 1; }
        kb=$(grep "Maximum resident" "run_$cmd.err" | awk '{print $NF}')
        wall=$(grep "Elapsed (wall" "run_$cmd.err" | awk '{print $NF}')
        note=$(grep -o "decimated by [0-9]* to [0-9.]* Hz" "run_$cmd.err" | head -1 || true)
        printf '%-10s %-11s %12.0f %12.0f %10s  %s\n' "$n" "$cmd" "$((kb / 1024))" \
            "$((kb * 1024 / n))" "$wall" "${note:-full rate in memory}"
    done
done
