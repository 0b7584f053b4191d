#!/usr/bin/env bash
# vfp against the numpy reference on one log, in interleaved rounds (README, "Against numpy"):
# each round runs `vfp identify LOG --family poly --json --chamber 0` (the whole process, GNU
# time) and then bench/numpy_poly_sweep.py LOG (its in-process time after the imports), so that
# both meet the same machine load. Prints each side's minimum, median and maximum wall time and
# the per-round ratio numpy / vfp.
#
#   bench/against_numpy.sh LOG [ROUNDS]    (VFP: the binary, default target/release/vfp;
#                                           PYTHON: one with numpy and pandas, default python3)
set -euo pipefail
LOG=$1
ROUNDS=${2:-30}
VFP=${VFP:-target/release/vfp}
PYTHON=${PYTHON:-python3}
HERE=$(dirname "$0")
pairs=$(mktemp)
trap 'rm -f "$pairs"' EXIT
for _ in $(seq 1 "$ROUNDS"); do
  v=$({ /usr/bin/time -f "%e" "$VFP" identify "$LOG" --family poly --json --chamber 0 >/dev/null; } 2>&1 | tail -1)
  n=$("$PYTHON" "$HERE/numpy_poly_sweep.py" "$LOG" | sed -n 's/.*: \([0-9]*\) ms wall.*/\1/p')
  echo "$v $n" >>"$pairs"
done
"$PYTHON" - "$pairs" <<'PY'
import statistics as st, sys
rows = [line.split() for line in open(sys.argv[1])]
v = [float(a) * 1000 for a, _ in rows]
n = [float(b) for _, b in rows]
r = [b / a for a, b in zip(v, n)]
fmt = lambda x: f"min {min(x):.0f}, median {st.median(x):.0f}, max {max(x):.0f} ms"
print(f"{len(rows)} rounds")
print(f"vfp (whole process):        {fmt(v)}")
print(f"numpy (in process):         {fmt(n)}")
print(f"numpy / vfp per round:      min {min(r):.2f}, median {st.median(r):.2f}, max {max(r):.2f}")
print(f"medians {st.median(n) / st.median(v):.2f}x, minima {min(n) / min(v):.2f}x")
PY
