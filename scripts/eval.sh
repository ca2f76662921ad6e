#!/usr/bin/env bash
# The accuracy evaluation behind the README's numbers, on all five sets at once: the built-in
# simulator (fresh scenes of every condition), ../shared/samples, ../shared/samples-hard, the
# simulator's generated 40-type catalogue and ../shared/samples-catalog; last, the simulator's
# touching and overlapping pairs again with a generated catalogue's types enrolled beside the
# three. Each set's templates are
# enrolled exactly as a new user would (types A/B/C or the simulator's three models as ids
# 1/2/3, both faces; a catalogue's folder in one `enroll --dir`, ids in name order; the unknown
# types never). Usage:
#   scripts/eval.sh [OUT_DIR]          (default target/eval; the simulated sets are kept there)
# Env: SIM_COUNT (scenes, default 180), SIM_SEED (default 11), CAT_COUNT (catalogue scenes,
# default 90), CAT_TYPES (default 40), MIXED_TYPES (catalogue types beside the three, default 40,
# at most 100).
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

# The catalogues: the simulator's (generated from the seed) and the shared one, each enrolled
# from its templates folder in one call (templates/unknown/ is never enrolled); eval reads the
# catalog.json beside each truth file for the revision families' table.
cat="$out/sim-catalog${CAT_TYPES:-40}-seed${SIM_SEED:-11}"
if [ ! -f "$cat/truth.jsonl" ]; then
  "$bin" simulate --out "$cat" --catalog "${CAT_TYPES:-40}" --seed "${SIM_SEED:-11}" --count "${CAT_COUNT:-90}" >/dev/null
fi
for set in "$cat" ../shared/samples-catalog; do
  if [ ! -f "$set/truth.jsonl" ]; then
    echo "== $set: truth.jsonl not found" >&2
    exit 1
  fi
  kb="$out/$(basename "$set").kb.toml"
  rm -f "$kb"
  "$bin" enroll --kb "$kb" --dir "$set/templates" >/dev/null
  echo "== $(basename "$set") ($set)"
  "$bin" eval --kb "$kb" --truth "$set/truth.jsonl"
done

# The simulator's touching and overlapping pairs of the three built-in types again, with
# MIXED_TYPES (default 40) types of a generated catalogue (seed 7) enrolled beside the three:
# what a larger catalogue does to the region search on scenes it does not change.
mixed_types=${MIXED_TYPES:-40}
pool="$out/sim-catalog100-seed7"
if [ ! -f "$pool/truth.jsonl" ]; then
  "$bin" simulate --out "$pool" --catalog 100 --seed 7 --count 1 >/dev/null
fi
kb="$out/sim-mixed$mixed_types.kb.toml"
cp "$out/sim.kb.toml" "$kb"
for k in $(seq 1 "$mixed_types"); do
  t=$(printf 'T%03d' "$k")
  for f in up down; do
    "$bin" enroll --kb "$kb" --type "$t" --id $((k + 3)) --face $f "$pool/templates/${t}_$f.png" >/dev/null
  done
done
grep -E '"condition":"(touching|overlapping)"' "$sim/truth.jsonl" >"$sim/pairs.jsonl"
echo "== the simulator's pairs, 3 + $mixed_types types enrolled ($sim/pairs.jsonl)"
"$bin" eval --kb "$kb" --truth "$sim/pairs.jsonl"
