#!/usr/bin/env bash
# Runs the tutorial's commands (docs/guide/src/tutorial.md) as a reader would type them: every
# `sh` block in order, in a scratch directory, with the built `vfp` first on the PATH. Blocks that
# need a board (a `--port`) are skipped: the virtual rig's `deploy` test runs `vfp deploy` on the
# firmware binary instead (rig-emu/tests/deploy.rs). Fails on the first command that fails.
#
#   docs/guide/run-tutorial.sh [VFP]      # VFP: the vfp binary (default target/debug/vfp)
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
vfp=${1:-$root/target/debug/vfp}
[ -x "$vfp" ] || { echo "run-tutorial: no vfp binary at $vfp (cargo build -p vfp)" >&2; exit 2; }
bin=$(mktemp -d)
work=$(mktemp -d)
trap 'rm -rf "$bin" "$work"' EXIT
ln -s "$vfp" "$bin/vfp"
export PATH="$bin:$PATH"

# The sh blocks, one command per line (comments and blank lines dropped).
commands=$(awk '
  /^```sh$/ { inside = 1; next }
  /^```/    { inside = 0; next }
  inside    { sub(/[ \t]+#.*$/, ""); if ($0 != "") print }
' "$root/docs/guide/src/tutorial.md")
[ -n "$commands" ] || { echo "run-tutorial: no sh block in the tutorial" >&2; exit 1; }

cd "$work"
ran=0
while IFS= read -r cmd; do
  case "$cmd" in
    *--port*) printf 'skipped (needs a board): %s\n' "$cmd"; continue ;;
  esac
  printf '$ %s\n' "$cmd"
  bash -c "$cmd -q" >/dev/null 2>"$work/stderr" || {
    cat "$work/stderr" >&2
    echo "run-tutorial: failed: $cmd" >&2
    exit 1
  }
  ran=$((ran + 1))
done <<<"$commands"
echo "run-tutorial: $ran commands ran"
