#!/usr/bin/env bash
# The accuracy evaluation behind the README's numbers, on all three sets at once: the built-in
# simulator (fresh scenes of every condition), ../shared/samples and ../shared/samples-hard.
# Each set's templates are enrolled exactly as a new user would (types A/B/C or the simulator's
# three models as ids 1/2/3, both faces; the unknown type never). Usage:
#   scripts/eval.sh [OUT_DIR]          (default target/eval; the simulated set is kept there)
# Env: SIM_COUNT (scenes, default 180), SIM_SEED (default 11).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/deps.sh
cargo build --release --bin lfi-bridge
bin=target/release/lfi-bridge
out=${1:-target/eval}
mkdir -p "$out"

enroll_set() { # DIR KB TYPE...
  local dir=$1 kb=$2; shift 2
  rm -f "$kb"
  local i=1
  for t in "$@"; do
    for f in up down; do
      "$bin" enroll --kb "$kb" --type "$t" --id $i --face $f "$dir/templates/${t}_$f.png" >/dev/null
    done
    i=$((i + 1))
  done
}

sim="$out/sim-seed${SIM_SEED:-11}"
if [ ! -f "$sim/truth.jsonl" ]; then
  "$bin" simulate --out "$sim" --count "${SIM_COUNT:-180}" --seed "${SIM_SEED:-11}" >/dev/null
fi
enroll_set "$sim" "$out/sim.kb.toml" bracket flange clevis
echo "== simulator ($sim)"
"$bin" eval --kb "$out/sim.kb.toml" --truth "$sim/truth.jsonl"

for set in samples samples-hard; do
  dir=../shared/$set
  if [ ! -f "$dir/truth.jsonl" ]; then
    echo "== $set: $dir/truth.jsonl not found" >&2
    exit 1
  fi
  enroll_set "$dir" "$out/$set.kb.toml" A B C
  echo "== $set ($dir)"
  "$bin" eval --kb "$out/$set.kb.toml" --truth "$dir/truth.jsonl"
done
