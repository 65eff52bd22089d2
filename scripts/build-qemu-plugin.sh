#!/bin/bash
# Builds the TCG instruction-count plugin (hil-tests/qemu/regioncount.c) against the plugin
# header of the installed QEMU. Debian ships no plugin header, so the header is taken from
# the matching Debian source package (`apt-get source`, deb-src stanza in a private sources
# dir derived from the machine's own; /etc is not touched, no mirror address is written).
# Idempotent. Output: target/qemu-plugins/libregioncount.so (path printed on stdout).
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
OUT="$ROOT/target/qemu-plugins"
SO="$OUT/libregioncount.so"
SRC="$ROOT/hil-tests/qemu/regioncount.c"
mkdir -p "$OUT"
if [ -f "$SO" ] && [ "$SO" -nt "$SRC" ]; then echo "$SO"; exit 0; fi
SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
pkg-config --exists glib-2.0 2>/dev/null || DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libglib2.0-dev >&2
HDR="$OUT/include/qemu-plugin.h"
if [ ! -f "$HDR" ]; then
  ver=$(dpkg-query -W -f='${Version}' qemu-system-arm)
  mm=$(echo "$ver" | sed 's/^[0-9]*://; s/^\([0-9]*\.[0-9]*\)\..*/\1/')   # e.g. 10.0
  SRC_DIR=${MAGCOMP_APT_SRC_DIR:-/tmp/magcomp-apt-src}
  mkdir -p "$SRC_DIR/lists/partial" "$SRC_DIR/cache/archives/partial"
  base=/etc/apt/sources.list.d/debian.sources
  # the installed backport, and the stable release it was backported from (same plugin API
  # within a QEMU X.Y series; a backport's source can be missing from the pool)
  awk 'BEGIN{RS=""; ORS="\n\n"} NR==1{print; exit}' "$base" \
    | sed 's/^Types:.*/Types: deb-src/; s/^Suites:.*/Suites: bookworm-backports trixie trixie-updates/' > "$SRC_DIR/src.sources"
  APT=(-o Dir::Etc::SourceParts="$SRC_DIR" -o Dir::Etc::SourceList=/dev/null
       -o Dir::State::Lists="$SRC_DIR/lists" -o Dir::Cache="$SRC_DIR/cache")
  apt-get "${APT[@]}" update -qq >&2
  work=$(mktemp -d); chmod 777 "$work"
  cands=$( (echo "$ver"; apt-cache "${APT[@]}" showsrc qemu | sed -n 's/^Version: //p') \
           | awk -v mm="$mm" '{u=$0; sub(/^[0-9]*:/,"",u); if (index(u, mm".")==1 && !seen[$0]++) print}')
  got=""
  for v in $cands; do
    if (cd "$work" && apt-get "${APT[@]}" source --download-only -qq "qemu=$v" >&2); then got=$v; break; fi
  done
  [ -n "$got" ] || { echo "no qemu $mm source package found" >&2; exit 1; }
  echo "plugin header from qemu source $got (installed $ver)" >&2
  orig=$(ls "$work"/qemu_*.orig.tar.* | head -1)
  mkdir -p "$OUT/include"
  tar -xf "$orig" -C "$work" --wildcards '*/include/qemu/qemu-plugin.h'
  cp "$(find "$work" -name qemu-plugin.h | head -1)" "$HDR"
  rm -rf "$work"
fi
gcc -O2 -shared -fPIC -I"$OUT/include" $(pkg-config --cflags glib-2.0) "$SRC" -o "$SO"
echo "$SO"
