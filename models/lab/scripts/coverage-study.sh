#!/usr/bin/env bash
# How much of the gel a press touches, against whether it is decided right
# (docs/benchmarks.md, "How much of the gel a press touches"). From the
# repository root: renders three sets of simulated presses by the held-out
# people 8-10 on units 0, 4 and 5 (119 textiles x 3 presses each, about
# 6.4 GB and 100 s per set), runs `telextilesd classify` on each with the
# shipped model against a jig index, and prints the table by coverage.
#
#   c1hand  catalogue 1, hand-held, against the shipped index (models/index.tlxi)
#   c1jig   catalogue 1, jig, against the shipped index
#   c2hand  catalogue 2, hand-held, against a catalogue-2 jig index
#           (people 0-1 on units 0-1, as docs/evaluation.md builds one)
set -euo pipefail
cargo build --release -p telextiles-lab -p telextilesd
LAB=target/release/telextiles-lab
D=${COVERAGE_DIR:-target/telextiles-lab/coverage}
mkdir -p "$D"
SETS=(--first 119 --presses 3 --sensors 0,4,5 --people 8,9,10)
$LAB sim-presses --out "$D/c1hand" "${SETS[@]}" --hand
$LAB sim-presses --out "$D/c1jig" "${SETS[@]}"
$LAB sim-presses --out "$D/c2hand" "${SETS[@]}" --hand --catalogue 2
[ -f "$D/c2.tlxi" ] || target/release/telextilesd index build --model models/encoder.onnx --sim \
    --catalogue 2 --people 2 --sensors 0,1 -o "$D/c2.tlxi"
for s in c1hand c1jig c2hand; do
    index=models/index.tlxi
    [ "$s" = c2hand ] && index=$D/c2.tlxi
    target/release/telextilesd classify --index "$index" --press "$D/$s" --json > "$D/$s.jsonl"
done
python3 models/lab/scripts/coverage_table.py c1hand="$D/c1hand.jsonl" c1jig="$D/c1jig.jsonl" \
    c2hand="$D/c2hand.jsonl"
