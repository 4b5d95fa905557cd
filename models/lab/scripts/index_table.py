"""Per index and set of presses: how `telextilesd classify` decided them.

Reads `classify --json` output (one press per line, each with its `source`
recording, labelled by the directory above it as `telextiles-lab
sim-presses` writes them) and prints a markdown table: presses, final and
first decisions right, presses flagged unknown, and the first decision's
time after the press began (p50), and the index search's time per frame
(the median over presses of each press's p50). For sets of fabrics the index does not
hold (ids starting with U), only the unknown flags count. Standard library
only.

    python3 index_table.py INDEX:SET=classify.jsonl [...]
"""
import json
import os
import statistics
import sys


def main(argv):
    print("| index | set | presses | right | first decision right | flagged unknown | first decision p50 (ms) | search per frame p50 (ms) |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for arg in argv:
        name, path = arg.split("=", 1)
        index, set_name = name.split(":", 1)
        with open(path) as f:
            rows = [json.loads(line) for line in f]
        if not rows:
            print(f"| {index} | {set_name} | 0 | | | | | |")
            continue
        n = len(rows)
        label = [os.path.basename(os.path.dirname(r["source"])) for r in rows]
        unseen = all(l.startswith("U") for l in label)
        right = sum(r.get("textile") == l for r, l in zip(rows, label))
        first = sum(r.get("first_textile") == l for r, l in zip(rows, label))
        flagged = sum(bool(r.get("unknown")) for r in rows)
        times = [r["decision_ms"] for r in rows if r.get("decision_ms") is not None]
        p50 = f"{statistics.median(times):.1f}" if times else "-"
        search = [r["stages"]["search"]["p50_ms"] for r in rows if "search" in r.get("stages", {})]
        search = f"{statistics.median(search):.3f}" if search else "-"
        pct = lambda k: f"{100.0 * k / n:.1f} %"
        if unseen:
            print(f"| {index} | {set_name} | {n} | – | – | {flagged} ({pct(flagged)}) | {p50} | {search} |")
        else:
            print(f"| {index} | {set_name} | {n} | {pct(right)} | {pct(first)} | {flagged} ({pct(flagged)}) | {p50} | {search} |")


if __name__ == "__main__":
    main(sys.argv[1:])
