#!/usr/bin/env bash
# Peak memory of `laserd send` streaming a large G-code file into the simulator
# on a pseudo-terminal (issue 3: under 50 MB for 1 GB).
#   bench/send-memory.sh [MEGABYTES] [BAUD]      (default: 1000 MB at 40 Mbaud)
# The file is CAM-style lines that do not move (the simulator runs in real time),
# each with a comment the sender strips. Needs /usr/bin/time (Debian: time).
set -euo pipefail
cd "$(dirname "$0")/.."
mb=${1:-1000}
baud=${2:-40000000}
cargo build --release --quiet
laserd=$PWD/target/release/laserd
work=$(mktemp -d)
trap 'kill "$sim" 2>/dev/null || true; rm -rf "$work"' EXIT
python3 - "$work/big.nc" "$mb" <<'PY'
import sys
path, mb = sys.argv[1], int(sys.argv[2])
line = b"G21 G90 G94 G17 G54 M5 M9 S0 F1000 T0 (a CAM tool's long comment, stripped)\n"
chunk = line * 10_000
with open(path, "wb") as f:
    written = 0
    while written < mb * 1_000_000:
        f.write(chunk)
        written += len(chunk)
PY
"$laserd" sim --pty --link "$work/tty" --baud "$baud" > "$work/sim.out" &
sim=$!
while [ ! -e "$work/tty" ]; do sleep 0.1; done
/usr/bin/time -v "$laserd" send "$work/big.nc" --port "$work/tty" --baud "$baud" --json > "$work/send.json" 2> "$work/time.txt"
echo "file: $(stat -c %s "$work/big.nc") bytes"
grep -E '"(completed|lines_sent|bytes_sent|stream_time_s)"' "$work/send.json"
grep -E "Maximum resident set size|Elapsed" "$work/time.txt"
