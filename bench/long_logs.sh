#!/usr/bin/env bash
# Long logs for the memory and time figures in the README ("Speed and memory"): simulated with
# host-sim (`vfp simulate`, the paper's five-rate protocol on SBA1, three chambers per frame, 25 Hz),
# then measured with GNU time (peak resident set, wall and CPU time). Nothing here is committed:
# the logs go to $OUT (default /tmp/vfp-bench).
#
#   bench/long_logs.sh [VFP]    VFP: the binary to measure (default: target/release/vfp)
#
# Logs (frames = samples per chamber; rows = 3 x frames):
#   c26.csv   26 cycles per rate:  ~84,600 frames  (the 83k-sample log of the identify comparison)
#   c83.csv   83 cycles per rate: ~270,000 frames  (3 hours at 25 Hz)
#   c205.csv 205 cycles per rate: ~667,000 frames, 2.0 M rows
# plus c13.csv and c42.csv (halves) to show that time grows linearly.
set -euo pipefail
VFP=${1:-target/release/vfp}
OUT=${OUT:-/tmp/vfp-bench}
mkdir -p "$OUT"
for c in 13 26 42 83 205; do
  [ -f "$OUT/c$c.csv" ] || "$VFP" simulate --preset paper --cycles "$c" -o "$OUT/c$c.csv" >/dev/null
done
measure() { # label, command...
  local label=$1; shift
  /usr/bin/time -f "$label: peak RSS %M KB, wall %e s, CPU %U+%S s" "$@" >/dev/null 2>"$OUT/time.err" || {
    cat "$OUT/time.err"; return 1; }
  tail -1 "$OUT/time.err"
}
for c in 13 26 42 83 205; do
  frames=$(grep -c '^[0-9.]*,0,' "$OUT/c$c.csv")
  measure "identify --family poly --json, c$c ($frames samples)" "$VFP" identify "$OUT/c$c.csv" --family poly --json
done
for c in 13 26 42 83; do
  frames=$(grep -c '^[0-9.]*,0,' "$OUT/c$c.csv")
  measure "diagnose --json, c$c ($frames samples)" "$VFP" diagnose "$OUT/c$c.csv" --json
done
if python3 -c 'import numpy, pandas' 2>/dev/null; then
  python3 bench/numpy_poly_sweep.py "$OUT/c26.csv"
else
  echo "numpy/pandas not installed: bench/numpy_poly_sweep.py not run"
fi
