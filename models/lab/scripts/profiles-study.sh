#!/usr/bin/env bash
# One fabric through two modes and two sensors' geometry
# (docs/studies/2026-12-05-sensor-profiles.md). From the repository root:
#
#   bash models/lab/scripts/profiles-study.sh
#
# Renders (or reuses) one hand-held set of 32 catalogue-2 fabrics in three
# geometries -- a DIGIT's QVGA (as rendered), its VGA at 30 fps, a GelSight
# Mini's 320x240 at 25 fps -- with the same seeds, builds a plain index per
# geometry, classifies every geometry's queries against every index and
# prints the paired table. About 15 minutes on 2 cores.
set -euo pipefail
BIN=${TELEXTILESD:-target/release/telextilesd}
[ -n "${TELEXTILESD:-}" ] || cargo build --release -p telextilesd
D=${PROFILES_DIR:-target/profiles-study}
mkdir -p "$D"
. models/lab/scripts/held-out-sets.sh

TEXTILES=$(for k in $(seq 0 31); do printf 'T%03d ' $((2 + 3 * k)); done)
declare -A GEOMETRY=(
    [qvga]=""
    [vga]="--sensor-profile digit --sensor-mode 640x480@30"
    [gs]="--sensor-profile gelsight-mini"
)
for g in qvga vga gs; do
    # shellcheck disable=SC2086
    UNSEEN=0 INDEX_PRESSES=3 make_set "$g" "$TEXTILES" "8 9" "4 5" "10 11" 6 \
        --catalogue 2 --no-jig ${GEOMETRY[$g]}
done
# gsnative: the GelSight geometry's images read as before profiles (their
# press.json naming no sensor: turned, not scaled).
if [ ! -d "$D/gsnative" ]; then
    cp -r "$D/gs" "$D/gsnative.part"
    find "$D/gsnative.part" -name press.json -print0 | xargs -0 python3 -c '
import json, sys
for p in sys.argv[1:]:
    m = json.load(open(p)); m.pop("sensor_profile", None); m.pop("mm_per_px", None)
    json.dump(m, open(p, "w"))'
    mv "$D/gsnative.part" "$D/gsnative"
fi
for i in qvga vga gs gsnative; do
    idx="$D/$i.tlxi"
    [ -f "$idx" ] || "$BIN" index build --model models/encoder.onnx --presses "$D/$i/index" \
        --catalogue 2 --features encoder --fit cosine \
        -o "$idx" > "$D/$i.build.txt"
    qs="qvga vga gs"
    [ "$i" != gsnative ] || qs="gsnative"
    for q in $qs; do
        out="$D/$i-$q.jsonl"
        [ -f "$out" ] || "$BIN" classify --index "$idx" --press "$D/$q/queries" --json \
            --mix-sensors 2>/dev/null > "$out.part"
        [ -f "$out" ] || mv "$out.part" "$out"
    done
done
python3 models/lab/scripts/profiles_table.py "$D"
