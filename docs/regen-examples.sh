#!/usr/bin/env bash
# Regenerates the user guide's console examples of the paper's diagnostics (§IV) and their figures
# from defaults, so what the guide shows is what a fresh clone prints.
#
#   bash docs/regen-examples.sh            # rewrite docs/guide/src/diagnostics.md's marked block and docs/guide/src/img/diag-*
#   bash docs/regen-examples.sh --check    # only print the block; exit 1 if docs/guide/src/diagnostics.md differs
#
# The simulated logs are the presets of `vfp simulate` with their default options (the paper's
# protocol, 20 cycles at each of 20–100 mm³/s; seeds as written below), written to a scratch
# directory. The block in docs/guide/src/diagnostics.md sits between the markers
#   <!-- regen-examples:diagnostics:begin -->  and  <!-- regen-examples:diagnostics:end -->
# and is replaced whole. Takes a few minutes (release build first, then eleven simulated runs).
set -euo pipefail
cd "$(dirname "$0")/.."

check=0
[ "${1:-}" = "--check" ] && check=1

cargo build --release --locked -q -p vfp --bin vfp
target_dir="${CARGO_TARGET_DIR:-target}"
case "$target_dir" in /*) ;; *) target_dir="$PWD/$target_dir" ;; esac
vfp="$target_dir/release/vfp"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
figs="$PWD/docs/guide/src/img"
[ "$check" = 1 ] && figs="$work/img"
mkdir -p "$figs"

sim() { "$vfp" simulate --quiet "$@"; }
sim --preset paper -o "$work/sba1.csv"
sim --preset paper --seed 2 -o "$work/sba1-rerun.csv"
for a in 0 10 20 40; do sim --preset "air:$a" -o "$work/air-$a.csv"; done
for d in 2 3 4; do sim --preset "design:sba$d" -o "$work/SBA$d.csv"; done
sim --preset force -o "$work/push.csv"

block="$work/block.md"
run() {
  # The command as the guide shows it (file names relative to the scratch directory).
  printf '$ vfp %s --plots docs/guide/src/img\n' "$*" >>"$block"
  (cd "$work" && "$vfp" --quiet "$@" --plots "$figs") >>"$block" 2>&1
  printf '\n' >>"$block"
}
{
  echo '<!-- regen-examples:diagnostics:begin -->'
  echo '```console'
} >"$block"
run stiffness sba1.csv
run air-scan air-0.csv air-10.csv air-20.csv air-40.csv --x 0,10,20,40 --chamber 0
run chow sba1.csv sba1-rerun.csv SBA2.csv SBA3.csv SBA4.csv
run force --ident sba1.csv --test push.csv
# Drop the blank line after the last command's output, then close the block.
sed -i '$ { /^$/d }' "$block"
{
  echo '```'
  echo '<!-- regen-examples:diagnostics:end -->'
} >>"$block"
sed -i "s#$figs#docs/guide/src/img#g; s#$work/##g" "$block"

new="$work/diagnostics.md"
awk -v block="$block" '
  /<!-- regen-examples:diagnostics:begin -->/ { while ((getline l < block) > 0) print l; skip = 1; next }
  /<!-- regen-examples:diagnostics:end -->/ { skip = 0; next }
  !skip { print }
' docs/guide/src/diagnostics.md >"$new"
if ! grep -q 'regen-examples:diagnostics:begin' docs/guide/src/diagnostics.md; then
  echo "docs/guide/src/diagnostics.md has no regen-examples markers" >&2
  exit 2
fi
if [ "$check" = 1 ]; then
  cat "$block"
  diff -u docs/guide/src/diagnostics.md "$new" && echo "docs/guide/src/diagnostics.md matches" || { echo "docs/guide/src/diagnostics.md differs" >&2; exit 1; }
else
  cp "$new" docs/guide/src/diagnostics.md
  echo "docs/guide/src/diagnostics.md block and docs/guide/src/img/diag-*.svg regenerated"
fi
