#!/usr/bin/env bash
# Fuzz the decoder for SECONDS (default 600): fuzz/run.sh [SECONDS] [extra libFuzzer flags]
# Needs the fuzz extra: pip install -e '.[fuzz]'. The working corpus starts from the
# conformance files and is kept in fuzz/corpus-work/ (not committed).
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-600}
shift || true
mkdir -p fuzz/corpus-work fuzz/crashes
cp -n format_spec/conformance/*.atm fuzz/corpus-work/ 2>/dev/null || true
exec python fuzz/fuzz_decode.py fuzz/corpus-work -max_total_time="$seconds" \
  -artifact_prefix=fuzz/crashes/ -max_len=65536 -timeout=10 -rss_limit_mb=4096 "$@"
