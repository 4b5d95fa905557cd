"""The paired table of profiles-study.sh: per (index geometry, query
geometry), the share of query presses whose final (and first) decision is
the fabric pressed, and against within-QVGA the paired difference with its
standard error (the same presses in each geometry)."""
import json
import math
import os
import sys

D = sys.argv[1]
G = ["qvga", "vga", "gs"]
PAIRS = [(i, q) for i in G for q in G] + [("gsnative", "gsnative")]


def results(i, q):
    out = {}
    with open(os.path.join(D, f"{i}-{q}.jsonl")) as f:
        for line in f:
            if not line.startswith("{"):
                continue
            v = json.loads(line)
            src = v.get("source", "")
            # .../queries/<textile>/<press>: the press, the same name in
            # every geometry.
            parts = src.rstrip("/").split("/")
            key, truth = "/".join(parts[-2:]), parts[-2]
            out[key] = (v.get("textile") == truth, v.get("first_textile") == truth)
    return out


base = results("qvga", "qvga")
print("| index | queries | presses | final right | first right | final vs QVGA/QVGA (paired) |")
print("|---|---|---:|---:|---:|---:|")
gs = results("gs", "gs")
for i, q in PAIRS:
        r = results(i, q)
        n = len(r)
        final = sum(a for a, _ in r.values()) / n
        first = sum(b for _, b in r.values()) / n
        common = [k for k in r if k in base]
        d = [r[k][0] - base[k][0] for k in common]
        m = sum(d) / len(d)
        sd = math.sqrt(sum((x - m) ** 2 for x in d) / max(len(d) - 1, 1))
        se = sd / math.sqrt(len(d))
        cmp = "—" if (i, q) == ("qvga", "qvga") else f"{100 * m:+.1f} ± {100 * se:.1f}"
        print(f"| {i} | {q} | {n} | {100 * final:.1f} % | {100 * first:.1f} % | {cmp} |")

# The GelSight Mini's two readings, paired on the same presses.
nat = results("gsnative", "gsnative")
common = [k for k in gs if k in nat]
for what, col in (("final", 0), ("first", 1)):
    d = [nat[k][col] - gs[k][col] for k in common]
    m = sum(d) / len(d)
    sd = math.sqrt(sum((x - m) ** 2 for x in d) / max(len(d) - 1, 1))
    print(f"\ngsnative - gs, {what} decisions, {len(d)} presses: {100 * m:+.1f} ± {100 * sd / math.sqrt(len(d)):.1f} points")
