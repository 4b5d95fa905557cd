#!/usr/bin/env bash
# Felt latency -- contact on the sending sensor until the wheel rests at the
# press's final sample -- for each motion policy, with the paper's wheel
# (docs/studies/2026-12-04-felt-latency.md). From the repository root:
#
#   bash models/lab/scripts/felt-study.sh
#
# Renders (or reuses) four simulated sets of 16 fabrics: c1jig (catalogue
# 1 in the jig, rendered here) and the fitted-metric study's three
# hand-held sets (held-out-sets.sh). For each, a 3-press plain index, then
# `classify` on the queries with every candidate policy, the felt-latency
# summary per policy (JSON) and its chart (SVG), and once more each with the
# slow wheel the firmware had before (1 rev/s, 2 rev/s^2) and with the fast
# end of what such a wheel does (5 rev/s, 100 rev/s^2). About 10
# minutes on 2 cores when the hand-held sets are already rendered
# (fit-study.sh), 35 otherwise; charts land in docs/studies/felt/.
set -euo pipefail
BIN=${TELEXTILESD:-target/release/telextilesd}
[ -n "${TELEXTILESD:-}" ] || cargo build --release -p telextilesd
D=${FIT_DIR:-target/fit-study}
CHARTS=${CHARTS:-docs/studies/felt}
mkdir -p "$D" "$CHARTS"
. models/lab/scripts/held-out-sets.sh

held_out_sets
UNSEEN=0 INDEX_PRESSES=3 make_set c1jig "$(seq16 3 7)" "0 1 2" "0" "3" 1 --catalogue 1

POLICIES=(every confident:0.25:100 confident:0.5:150 lead:15 lead:30 lead:60 track:30 track:60 track:100)
motion=()
for p in "${POLICIES[@]}"; do motion+=(--motion "$p"); done

for set in c1jig c2hand c1units c2g2; do
    cat=1
    case $set in c2*) cat=2 ;; esac
    idx="$D/$set-3-plain.tlxi"
    [ -f "$idx" ] || "$BIN" index build --model models/encoder.onnx --presses "$D/$set/index3" \
        --catalogue "$cat" --features encoder --fit cosine -o "$idx" > "$D/$set-3-plain.build.txt"
    echo "== $set" >&2
    "$BIN" classify --index "$idx" --press "$D/$set/queries" "${motion[@]}" \
        --felt-json "$D/felt-$set.json" --felt-svg "$CHARTS/$set.svg" 2>/dev/null |
        grep -E "^wheel|^summary"
    "$BIN" classify --index "$idx" --press "$D/$set/queries" --motion every \
        --wheel-speed 3200 --wheel-accel 6400 --felt-json "$D/felt-$set-slow.json" 2>/dev/null |
        grep -E "^wheel" | sed 's/^wheel (every)/wheel (every, slow wheel)/'
    "$BIN" classify --index "$idx" --press "$D/$set/queries" --motion every \
        --wheel-speed 16000 --wheel-accel 320000 --felt-json "$D/felt-$set-fast.json" 2>/dev/null |
        grep -E "^wheel" | sed 's/^wheel (every)/wheel (every, fast wheel)/'
done
