#!/usr/bin/env bash
# Long logs for the memory and time figures in the README ("Speed and memory"), and the residual
# loop's budgets of issue 33. Logs are simulated with host-sim (`vfp simulate`, the paper's
# five-rate protocol on SBA1, three chambers per frame, 25 Hz) and measured with GNU time (peak
# resident set, wall and CPU time). Nothing here is committed: the logs go to $OUT (default
# /tmp/vfp-bench).
#
#   bench/long_logs.sh [--budgets | --scaling | --all] [VFP]
#       --budgets  only the loop's budgets (below); exit status 1 when one is over
#       --scaling  only the scaling series (identify and diagnose on growing logs)
#       --all      both (the default)
#       VFP        the binary to measure (default: target/release/vfp)
#
# Scaling logs (frames = samples per chamber; rows = 3 x frames):
#   c26.csv   26 cycles per rate:  ~84,600 frames  (the 83k-sample log of the identify comparison)
#   c83.csv   83 cycles per rate: ~270,000 frames  (3 hours at 25 Hz)
#   c205.csv 205 cycles per rate: ~667,000 frames, 2.0 M rows
# plus c13.csv and c42.csv (halves) to show that time grows linearly.
#
# Budgets (issue 33; a 2-core machine, release build), each printed beside its measurement:
#   - `vfp diagnose --json` on the 3-hour log (c83.csv): wall <= 45 s, peak RSS <= 400 MB;
#   - `vfp demo` (full, not --short): wall <= 20 s;
#   - `vfp diagnose --json` on a fixed set of 20k-sample logs of the paper's protocol (6 cycles per
#     rate, ~19,400 samples): no effect, one plant effect each (hysteresis, air, sensor lag,
#     backlash, inertance) and three at once (bench/protocol-three-effects.toml): CPU time
#     (user + sys) median <= 2 s, worst <= 10 s.
# CPU seconds are the figure to trust on a shared machine: other processes inflate wall time
# much more than CPU time. Wall budgets are measured all the same, as a user meets them.
# Not a test: timed tests fail on a busy machine; run it by hand (or in a quiet CI step).
set -euo pipefail
MODE=all
case "${1:-}" in
  --budgets) MODE=budgets; shift ;;
  --scaling) MODE=scaling; shift ;;
  --all) shift ;;
esac
VFP=${1:-target/release/vfp}
OUT=${OUT:-/tmp/vfp-bench}
HERE=$(dirname "$0")
mkdir -p "$OUT"
measure() { # label, command...
  local label=$1; shift
  /usr/bin/time -f "$label: peak RSS %M KB, wall %e s, CPU %U+%S s" "$@" >/dev/null 2>"$OUT/time.err" || {
    cat "$OUT/time.err"; return 1; }
  tail -1 "$OUT/time.err"
}
quiet() { # command...: its output only when it fails
  "$@" >"$OUT/quiet.log" 2>&1 || { cat "$OUT/quiet.log"; return 1; }
}
sim() { # cycles -> $OUT/c$cycles.csv
  [ -f "$OUT/c$1.csv" ] || quiet "$VFP" simulate --preset paper --cycles "$1" -q -o "$OUT/c$1.csv"
}

if [ "$MODE" != budgets ]; then
  for c in 13 26 42 83 205; do sim "$c"; done
  for c in 13 26 42 83 205; do
    frames=$(grep -c '^[0-9.]*,0,' "$OUT/c$c.csv")
    measure "identify --family poly --json, c$c ($frames samples)" "$VFP" identify "$OUT/c$c.csv" --family poly --json
  done
  for c in 13 26 42 83; do
    frames=$(grep -c '^[0-9.]*,0,' "$OUT/c$c.csv")
    measure "diagnose --json, c$c ($frames samples)" "$VFP" diagnose "$OUT/c$c.csv" --json
  done
  if python3 -c 'import numpy, pandas' 2>/dev/null; then
    python3 "$HERE/numpy_poly_sweep.py" "$OUT/c26.csv"
  else
    echo "numpy/pandas not installed: bench/numpy_poly_sweep.py not run"
  fi
fi
[ "$MODE" = scaling ] && exit 0

# ---- budgets ----
over=0
verdict() { # name, value, budget, unit
  if awk -v v="$2" -v b="$3" 'BEGIN { exit !(v <= b) }'; then
    printf '  %-44s %10s %s  (budget <= %s %s)  ok\n' "$1" "$2" "$4" "$3" "$4"
  else
    printf '  %-44s %10s %s  (budget <= %s %s)  OVER\n' "$1" "$2" "$4" "$3" "$4"
    over=1
  fi
}
# GNU time's figures for one command: "wall cpu peak_kb", the command's stdout to $OUT/last.out.
timed() {
  /usr/bin/time -f "%e %U %S %M" -o "$OUT/time.txt" "$@" >"$OUT/last.out" 2>"$OUT/time.err" || {
    cat "$OUT/time.err"; return 1; }
  awk '{ printf "%.2f %.2f %d\n", $1, $2 + $3, $4 }' "$OUT/time.txt"
}
echo "budgets (issue 33; CPU = user + sys)"

sim 83
read -r wall cpu kb < <(timed "$VFP" diagnose "$OUT/c83.csv" --json)
frames=$(grep -c '^[0-9.]*,0,' "$OUT/c83.csv")
verdict "3-hour log ($frames samples), diagnose wall" "$wall" 45 s
verdict "3-hour log, diagnose peak RSS" "$((kb / 1024))" 400 MB
echo "    (CPU $cpu s; the loop's stages: timing_s in $OUT/c83-diagnose.json)"
cp "$OUT/last.out" "$OUT/c83-diagnose.json"

read -r wall cpu kb < <(timed "$VFP" demo --out "$OUT/demo")
verdict "vfp demo wall" "$wall" 20 s
echo "    (CPU $cpu s, peak RSS $((kb / 1024)) MB; the demo's log: $OUT/demo/identification.csv)"

# The fixed protocol set: 6 cycles per rate, fixed seeds.
logs=()
for spec in paper:1 effect:hysteresis:1 effect:air:2 effect:sensor-lag:3 effect:backlash:4 effect:inertance:5; do
  preset=${spec%:*}
  seed=${spec##*:}
  f="$OUT/p6-${preset//:/-}-s$seed.csv"
  [ -f "$f" ] || quiet "$VFP" simulate --preset "$preset" --cycles 6 --seed "$seed" -q -o "$f"
  logs+=("$f")
done
f="$OUT/p6-three-effects.csv"
[ -f "$f" ] || quiet "$VFP" simulate --scenario "$HERE/protocol-three-effects.toml" -q -o "$f"
logs+=("$f")
cpus=()
for f in "${logs[@]}"; do
  read -r wall cpu kb < <(timed "$VFP" diagnose "$f" --json)
  named=$(python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); print(",".join(e["name"] for e in d["effects"]) or "-")' "$OUT/last.out" 2>/dev/null || echo "?")
  printf '    %-40s CPU %6.2f s, wall %6.2f s, %4d MB; named: %s\n' "$(basename "$f")" "$cpu" "$wall" "$((kb / 1024))" "$named"
  cpus+=("$cpu")
done
read -r median worst < <(printf '%s\n' "${cpus[@]}" | sort -g | awk '{ v[NR] = $1 } END {
  m = (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2; printf "%.2f %.2f\n", m, v[NR] }')
verdict "protocol logs (${#logs[@]}), diagnose CPU median" "$median" 2 s
verdict "protocol logs, diagnose CPU worst" "$worst" 10 s
exit "$over"
