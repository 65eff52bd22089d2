#!/bin/bash
# Target benchmarks: guest instructions per filter step on the Cortex-M4F (QEMU
# netduinoplus2, STM32F405), counted by the TCG plugin hil-tests/qemu/regioncount.c between
# the marker functions of src/bin/kf_bench.rs; plus flash/RAM of the release firmware.
# Needs: scripts/install-qemu.sh (QEMU 10, binutils-arm-none-eabi). Prints a table.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
cd "$ROOT"
ELF=$(scripts/build-emu.sh --bin kf_bench | tail -1)
PLUGIN=$(scripts/build-qemu-plugin.sh | tail -1)
sym() { printf '0x%x' $(( 0x$(arm-none-eabi-nm "$ELF" | awk -v s="$1" '$3==s{print $1}') & ~1 )); }
count() { # region -> "n mean min max"
  local b e log; b=$(sym "bench_$1_begin"); e=$(sym "bench_$1_end"); log=$(mktemp)
  timeout 60 qemu-system-arm -M netduinoplus2 -display none -monitor none \
    -semihosting-config enable=on,target=native -kernel "$ELF" \
    -serial null -serial null -serial null -serial null -serial null \
    -plugin "$PLUGIN,begin=$b,end=$e" -d plugin -D "$log" >/dev/null 2>&1 || true
  local line; line=$(grep regioncount "$log" | tail -1); rm -f "$log"
  echo "$line"
}
field() { sed -n "s/.*$2=\([0-9.]*\).*/\1/p" <<<"$1"; }
declare -A MEAN
printf '%-10s %-58s %10s %8s %8s\n' region "what" "instr/step" min max
desc() { case $1 in
  empty) echo "marker pair alone (subtracted below)";;
  comp21) echo "Compensator::push, tl16+field (21 states), calibrate";;
  comp27) echo "Compensator::push, tl16+field+rate (27 states)";;
  tu21) echo "UD time update (MWGS, 5 field states), n=21";;
  mu21) echo "UD scalar measurement update (Bierman), n=21";;
  tu27) echo "UD time update, n=27";;
  mu27) echo "UD scalar measurement update, n=27";;
  kf21) echo "plain covariance KF step (core CovFilter), n=21";;
  kf27) echo "plain covariance KF step, n=27";;
  sample21) echo "board per-sample path: parse+align+push+encode, 21";;
  epoch) echo "EpochBuilder::push alone (comp21 minus process)";;
  sample3) echo "3 magnetometers on a counter line: parse+align+3 push+encode";;
esac; }
for r in empty comp21 comp27 tu21 mu21 tu27 mu27 kf21 kf27 sample21 epoch sample3; do
  l=$(count $r)
  m=$(field "$l" mean); mn=$(field "$l" min); mx=$(field "$l" max)
  MEAN[$r]=${m%.*}
  ov=${MEAN[empty]:-0}
  [ "$r" = empty ] && ov=0
  printf '%-10s %-58s %10s %8s %8s\n' "$r" "$(desc $r)" "$(( ${m%.*} - ov ))" "$(( ${mn:-0} - ov ))" "$(( ${mx:-0} - ov ))"
done
e=${MEAN[empty]}
printf '%-10s %-58s %10s\n' "ud21" "UD step = time + measurement update, n=21" "$(( ${MEAN[tu21]} + ${MEAN[mu21]} - 2 * e ))"
printf '%-10s %-58s %10s\n' "ud27" "UD step = time + measurement update, n=27" "$(( ${MEAN[tu27]} + ${MEAN[mu27]} - 2 * e ))"
s=$(( ${MEAN[sample21]} - ${MEAN[empty]} ))
echo
echo "highest scalar rate, CPU bound, at 168 MHz and 1.2-1.6 cycles/instruction, 50 % CPU budget:"
echo "  $(( 168000000 / 2 * 10 / 16 / s )) - $(( 168000000 / 2 * 10 / 12 / s )) Hz (per-sample path $s instructions)"
s3=$(( ${MEAN[sample3]} - ${MEAN[empty]} ))
echo "3 magnetometers on a counter line ($s3 instructions per line):"
echo "  CPU at 1 kHz: $(( s3 * 12 / 16800 )) - $(( s3 * 16 / 16800 )) %; highest rate at 50 % CPU: $(( 168000000 / 2 * 10 / 16 / s3 )) - $(( 168000000 / 2 * 10 / 12 / s3 )) Hz"
FW="$ROOT/target/thumbv7em-none-eabihf/fw/magcomp-firmware"
cargo build -q --profile fw --target thumbv7em-none-eabihf -p magcomp-firmware --bin magcomp-firmware
echo
echo "release firmware (acquisition board):"
arm-none-eabi-size "$FW" | awk 'NR==2{printf "  flash %d B (%.1f KiB), static RAM %d B (%.1f KiB)\n", $1+$2, ($1+$2)/1024, $2+$3, ($2+$3)/1024}'
if command -v cargo-bloat >/dev/null; then
  echo
  echo "code by crate (cargo bloat; cargo install cargo-bloat):"
  cargo bloat -q --profile fw --target thumbv7em-none-eabihf -p magcomp-firmware --bin magcomp-firmware --crates -n 12 2>/dev/null | sed 's/^/  /'
fi
