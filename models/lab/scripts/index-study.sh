#!/usr/bin/env bash
# Simulated indexes compared as the daemon decides presses against them
# (docs/benchmarks.md, "The shipped index with every press and a learned
# distance: measured, not shipped"). From the repository root: renders
# (or reuses) three sets of simulated catalogue-1 presses by the held-out
# people 8-10 on units 0, 4 and 5 -- hand-held and jig presses of the 119
# known fabrics (3 each) and jig presses of the 20 unseen ones (6 each) --
# runs `telextilesd classify` on each against every index given, and
# prints one table. About 4 minutes per index once the presses exist
# (rendering them: about 100 s per set, 6.4 GB for each known set).
#
#   bash models/lab/scripts/index-study.sh [NAME=INDEX ...]
#
# Default: shipped=models/index.tlxi. The study of 2026-12-02 compared it
# with two indexes of the same presses built as an owner's is (each about
# 15-28 minutes on this 2-core VM):
#   telextilesd index build --model models/encoder.onnx --sim --people 8 \
#       --sensors 0,1,2,3 --exemplars --metric --calibrate-unknown -o calibrated.tlxi
#   (the same without --calibrate-unknown) -o fixed.tlxi
set -euo pipefail
cargo build --release -p telextiles-lab -p telextilesd
LAB=target/release/telextiles-lab
D=${COVERAGE_DIR:-target/telextiles-lab/coverage}
mkdir -p "$D"
SETS=(--sensors 0,4,5 --people 8,9,10)
$LAB sim-presses --out "$D/c1hand" --first 119 --presses 3 "${SETS[@]}" --hand
$LAB sim-presses --out "$D/c1jig" --first 119 --presses 3 "${SETS[@]}"
$LAB sim-presses --out "$D/c1unseen" --textiles "$(seq -f 'U%02g' 1 20 | paste -sd,)" \
    --presses 6 "${SETS[@]}"
[ $# -gt 0 ] || set -- shipped=models/index.tlxi
args=()
for spec in "$@"; do
    name=${spec%%=*}
    file=${spec#*=}
    for s in c1hand c1jig c1unseen; do
        target/release/telextilesd classify --index "$file" --press "$D/$s" --json > "$D/$s-$name.jsonl"
        args+=("$name:$s=$D/$s-$name.jsonl")
    done
done
python3 models/lab/scripts/index_table.py "${args[@]}"
