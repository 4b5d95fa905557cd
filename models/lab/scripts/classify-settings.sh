#!/usr/bin/env bash
# The decision-speed settings as an owner replays them: `telextilesd
# classify` on simulated recordings, with the daemons' settings that trade
# first decisions for speed (`encode_run`, `commit_margin`, `contact_tile`
# with `contact_enter`). The figures of docs/recording.md, "Choosing the
# decision-speed settings on your own presses".
#
#   bash models/lab/scripts/classify-settings.sh
#
# Three sets (presses already written are kept): catalogue 1, 24 textiles x
# 8 presses, people 8-10, units 0, 4, 5, held by hand and in the jig; and
# catalogue 2's C2HAND of sets.sh (40 textiles x 8 hand-held presses, as
# recorded-sets.sh renders them). The first 4 presses of each textile (sorted) build the index
# (`index build --presses`, its defaults), the others are queries. Times
# count from each press's true first contact, which simulated recordings
# carry (press.json `params.contact_frame`); real recordings do not, so
# on yours read `start_ms + decision_ms` against each other. Report:
# docs/bench-v2/classify-settings/report.md. About 25 minutes on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/../../.."
cargo build --release -p telextiles-lab -p telextilesd
LAB=target/release/telextiles-lab
D=target/release/telextilesd
T=target/telextiles-lab/classify-settings
OUT=docs/bench-v2/classify-settings
mkdir -p "$T" "$OUT"
$LAB sim-presses --out $T/c1jig --first 24 --presses 8 --sensors 0,4,5 --people 8,9,10 > /dev/null
$LAB sim-presses --out $T/c1hand --first 24 --presses 8 --sensors 0,4,5 --people 8,9,10 --hand > /dev/null
# shellcheck source=models/lab/scripts/sets.sh
source models/lab/scripts/sets.sh
$LAB sim-presses --out $T/c2hand "${C2HAND[@]}" > /dev/null
SETTINGS=(
    ""
    "--encode-run"
    "--commit-margin 0.02"
    "--encode-run --commit-margin 0.02"
    "--contact-tile 10 --contact-enter 0.6"
    "--contact-tile 10 --contact-enter 0.6 --encode-run --commit-margin 0.02"
)
rows=$T/rows.jsonl
: > "$rows"
for set in c1jig c1hand c2hand; do
    cat=1
    [ "$set" = c2hand ] && cat=2
    rm -rf "$T/split-$set"
    for t in "$T/$set"/*/; do
        n=0
        for p in $(ls "$t"); do
            part=query
            [ $n -lt 4 ] && part=index
            mkdir -p "$T/split-$set/$part/$(basename "$t")"
            ln -s "$(realpath "$t/$p")" "$T/split-$set/$part/$(basename "$t")/$p"
            n=$((n + 1))
        done
    done
    $D index build --model models/encoder.onnx --presses "$T/split-$set/index" \
        --catalogue $cat --slots 16 -o "$T/$set.tlxi" > /dev/null 2>&1
    for s in "${SETTINGS[@]}"; do
        # shellcheck disable=SC2086
        $D classify --model models/encoder.onnx --index "$T/$set.tlxi" \
            --press "$T/split-$set/query" --json $s 2> /dev/null |
            python3 -c 'import json, sys
for l in sys.stdin:
    r = json.loads(l); r["set"] = sys.argv[1]; r["settings"] = sys.argv[2]
    print(json.dumps(r))' "$set" "$s" >> "$rows"
        echo "classified $set with [${s:-shipped}]"
    done
done
python3 - "$rows" "$OUT/report.md" <<'PY'
import json, os, statistics, sys

rows = [json.loads(l) for l in open(sys.argv[1])]
meta = {}
def press(r):
    """The recording's label and true first contact (ms from its first frame)."""
    src = r["source"]
    if src not in meta:
        m = json.load(open(os.path.join(src, "press.json")))
        meta[src] = (m["textile"], m["timestamps_us"][m["params"]["contact_frame"]] / 1e3)
    return meta[src]

def right_at(r, label, contact, ms):
    """Whether the decision in force `ms` after the true contact is the
    label (a press that changed decision twice or more before then is
    read as its first decision until its last change)."""
    # A decision on a frame exactly `ms` after contact counts (as in the
    # decider-timing studies); 1 µs absorbs the decimal milliseconds.
    if r["textile"] is None or r["start_ms"] + r["decision_ms"] > contact + ms + 1e-3:
        return False
    if r["start_ms"] + r["stable_ms"] <= contact + ms + 1e-3:
        return r["textile"] == label
    return r["first_textile"] == label

out = ["# Decision-speed settings replayed with `telextilesd classify`", "",
       "Made by `bash models/lab/scripts/classify-settings.sh` (simulated recordings;",
       "the script's header says what the sets are). Per set and settings: the query",
       "presses, those decided, the first decision right (the roller's first move),",
       "right at the end of the press, right 100 ms and 250 ms after the true first",
       "contact, the first decision's time after the true contact (median, 90th",
       "percentile) and the changes of decision (all presses).", "",
       "| set | settings | presses | decided | first decision right | right at the end | right at 100 ms | right at 250 ms | first decision, ms p50 / p90 | changes |",
       "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
seen = []
for r in rows:
    key = (r["set"], r["settings"])
    if key not in seen:
        seen.append(key)
pct = lambda k, n: f"{100 * k / n:.1f} %" if n else "-"
for key in seen:
    rs = [r for r in rows if (r["set"], r["settings"]) == key]
    n = len(rs)
    dec = [r for r in rs if r["textile"] is not None]
    first = sum(r["first_textile"] == press(r)[0] for r in dec)
    last = sum(r["textile"] == press(r)[0] for r in dec)
    at = lambda ms: sum(right_at(r, *press(r), ms) for r in rs)
    after = sorted(r["start_ms"] + r["decision_ms"] - press(r)[1] for r in dec)
    p90 = after[min(len(after) - 1, int(0.9 * len(after)))] if after else float("nan")
    p50 = statistics.median(after) if after else float("nan")
    out.append(f"| {key[0]} | `{key[1] or '(shipped)'}` | {n} | {len(dec)} | {pct(first, n)} "
               f"| {pct(last, n)} | {pct(at(100), n)} | {pct(at(250), n)} | {p50:.0f} / {p90:.0f} "
               f"| {sum(r['switches'] for r in rs)} |")
open(sys.argv[2], "w").write("\n".join(out) + "\n")
print(f"wrote {sys.argv[2]}")
PY
