#!/bin/bash
# Compares the board records ($MCREC lines) of two hil-tests runs line by line: e.g. the
# emulated firmware before and after a change that must not alter any output.
#   MAGCOMP_HIL_KEEP=1 TMPDIR=/tmp/hil-a MAGCOMP_FW_ELF=old.elf ... cargo test -p hil-tests
#   MAGCOMP_HIL_KEEP=1 TMPDIR=/tmp/hil-b MAGCOMP_FW_ELF=new.elf ... cargo test -p hil-tests
#   scripts/hil-records-diff.sh /tmp/hil-a /tmp/hil-b
# Each run directory (magcomp-hil-PID-NAME) is matched by NAME; prints the records compared
# and differing per run, exits 1 on any difference or a run missing on either side.
set -euo pipefail
A=${1:?usage: hil-records-diff.sh DIR_A DIR_B}; B=${2:?usage: hil-records-diff.sh DIR_A DIR_B}
total=0; differ=0; bad=0
for da in "$A"/magcomp-hil-*; do
  name=${da##*/}; name=${name#magcomp-hil-}; name=${name#*-}
  db=$(ls -d "$B"/magcomp-hil-*-"$name" 2>/dev/null | head -1)
  if [ -z "$db" ] || [ ! -f "$da/output.txt" ] || [ ! -f "$db/output.txt" ]; then
    echo "$name: missing on one side"; bad=1; continue
  fi
  ra=$(grep -c '^\$MCREC' "$da/output.txt" || true); rb=$(grep -c '^\$MCREC' "$db/output.txt" || true)
  d=$(cmp -s <(grep '^\$MCREC' "$da/output.txt") <(grep '^\$MCREC' "$db/output.txt") && echo 0 ||
      diff <(grep '^\$MCREC' "$da/output.txt") <(grep '^\$MCREC' "$db/output.txt") | grep -c '^<' || true)
  [ "$ra" = "$rb" ] || d="$d (counts $ra / $rb)"
  echo "$name: $ra records, $d differ"
  total=$((total + ra)); [ "$d" = 0 ] || differ=1
done
echo "total $total records; $([ $differ = 0 ] && [ $bad = 0 ] && echo identical || echo DIFFERENT)"
[ $differ = 0 ] && [ $bad = 0 ]
