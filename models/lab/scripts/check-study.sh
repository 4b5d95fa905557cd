#!/usr/bin/env bash
# Does `telextilesd index check`, run on an owner's presses, pick the model
# that does better on presses it has not seen? On each simulated recorded
# set of recorded-sets.sh, and on a catalogue-1 set of the same shape
# (c1hand), the presses are split in two halves with every person and
# sensor unit in both, and on two sets of catalogue 2's unseen book
# (U01-U20: fabrics the shipped model's head never saw, rendered by each
# texture generator): "own" (each textile's first half of press numbers)
# and "later" (the rest). `index check` runs on "own" with the shipped
# model and the shipped fallback (models/descriptor.onnx); then, as an
# owner would, `index build --presses own` and `classify --press later`
# with each model. The report compares the check's pick with the model
# that decided more of the later presses right.
#
#   bash models/lab/scripts/check-study.sh [OUT]   (default docs/bench-v2/check)
#
# SETS="c2unseen c2g2unseen" runs only those, SETS=" " none (the report
# covers the sets whose results are in OUT). About 25 minutes on 2 cores once the sets
# exist.
set -euo pipefail
cd "$(dirname "$0")/../../.."
# shellcheck source=recorded-sets.sh
. models/lab/scripts/recorded-sets.sh
OUT=${1:-docs/bench-v2/check}
$LAB sim-presses --out $T/c1hand --first 40 --presses 8 \
    --sensors 0,4,5,6 --people 8,9,10,11 --hand
UNSEEN=$(seq -f "U%02g" 1 20 | paste -sd,)
$LAB sim-presses --out $T/c2unseen --catalogue 2 --textiles "$UNSEEN" --presses 8 \
    --sensors 0,4,5,6 --people 8,9,10,11 --hand --seed 21
$LAB sim-presses --out $T/c2g2unseen --catalogue 2 --generator 2 --textiles "$UNSEEN" \
    --presses 8 --sensors 1,7,8,9 --people 0,3,5,7 --hand --seed 31
cargo build --release -p telextilesd
D=target/release/telextilesd
mkdir -p "$OUT"
declare -A MODEL=([shipped]=models/encoder.onnx [fallback]=models/descriptor.onnx)
for set in ${SETS:-simrec/recordings c2hand c2g2hand c1hand c2unseen c2g2unseen}; do
    name=${set%%/*}
    split=$T/check/$name
    rm -rf "$split"
    # Halves by press number (the recordings are named p<person>-s<unit>-<k>,
    # k = 0.. per textile, people and units taking turns).
    for tdir in "$T/$set"/*/; do
        t=$(basename "$tdir")
        n=$(find "$tdir" -mindepth 1 -maxdepth 1 -type d | wc -l)
        for p in "$tdir"*/; do
            k=$((10#$(basename "$p" | sed 's/.*-//')))
            half=later
            [ $((k % n)) -lt $((n / 2)) ] && half=own
            mkdir -p "$split/$half/$t"
            ln -s "$(realpath "$p")" "$split/$half/$t/$(basename "$p")"
        done
    done
    $D index check --presses "$split/own" --model models/encoder.onnx \
        --model models/descriptor.onnx --json > "$OUT/$name-check.json"
    for m in shipped fallback; do
        $D index build --presses "$split/own" --model "${MODEL[$m]}" \
            -o "$split/$m.tlxi" > /dev/null 2>&1
        $D classify --press "$split/later" --model "${MODEL[$m]}" \
            --index "$split/$m.tlxi" --json > "$OUT/$name-$m-later.jsonl"
    done
    echo "$name done"
done
python3 - "$OUT" <<'PY'
import json, os, sys
out = sys.argv[1]
rows = []
for name in ["simrec", "c1hand", "c2hand", "c2g2hand", "c2unseen", "c2g2unseen"]:
    if not os.path.exists(f"{out}/{name}-check.json"):
        continue
    check = json.load(open(f"{out}/{name}-check.json"))
    later, hits = {}, {}
    for m in ["shipped", "fallback"]:
        reps = [json.loads(l) for l in open(f"{out}/{name}-{m}-later.jsonl") if l.startswith("{")]
        hits[m] = {(r["source"], r.get("press")): r.get("textile") == os.path.basename(os.path.dirname(r["source"].rstrip("/"))) for r in reps}
        later[m] = (sum(hits[m].values()), len(reps))
    both = hits["shipped"].keys() & hits["fallback"].keys()
    later_only = (sum(1 for k in both if hits["shipped"][k] and not hits["fallback"][k]),
                  sum(1 for k in both if hits["fallback"][k] and not hits["shipped"][k]))
    s, f = check["models"]
    pick = "shipped" if check["choice"] == s["model"] else "fallback"
    shares = {m: later[m][0] / later[m][1] for m in later}
    better = "tie" if shares["shipped"] == shares["fallback"] else max(shares, key=shares.get)
    rows.append((name, check, s, f, later, pick, better, later_only))
with open(f"{out}/report.md", "w") as w:
    w.write("# `index check` on the owner's presses against classify on later presses\n\n")
    w.write("Written by `bash models/lab/scripts/check-study.sh`. Per set: the self-check of each model on the \"own\" half "
            "(each press left out and decided against an index of the other own presses), the paired comparison, "
            "the check's pick, and each model's top-1 on the \"later\" half (`classify` against `index build --presses own`).\n\n")
    w.write("| set | own presses checked | shipped: self-check | fallback: self-check | right by one only (shipped / fallback) | check's pick | later presses (as classify reports them) | shipped: later | fallback: later | right by one only (shipped / fallback) | better on later |\n")
    w.write("|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---|\n")
    for name, check, s, f, later, pick, better, later_only in rows:
        a = f["against_first"]
        pct = lambda r, n: f"{100 * r / n:.1f} %"
        w.write(f"| {name} | {s['presses']} | {pct(s['right'], s['presses'])} | {pct(f['right'], f['presses'])} | "
                f"{a['right_only_first']} / {a['right_only_this']} | {pick} | {later['shipped'][1]} | "
                f"{pct(*later['shipped'])} | {pct(*later['fallback'])} | {later_only[0]} / {later_only[1]} | {better} |\n")
print(open(f"{out}/report.md").read())
PY
