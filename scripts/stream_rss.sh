#!/usr/bin/env bash
# Peak memory of `compensate --coeffs` streamed and in memory at 1 M and 10 M rows
# (host/benches/stream_rss.rs says how the inputs are made). Usage:
#   scripts/stream_rss.sh                      # 1,000,000 and 10,000,000 rows
#   STREAM_RSS_ROWS=200000 scripts/stream_rss.sh
#   STREAM_RSS_SENSORS=3 STREAM_RSS_ROWS=250000,1000000 STREAM_RSS_IN_MEMORY_MAX=250000 \
#     scripts/stream_rss.sh                    # three magnetometers, one filter each
set -euo pipefail
cd "$(dirname "$0")/.."
exec nice -n 10 cargo bench -p magcomp --bench stream_rss
