"""Per-press accuracy against how much of the gel a press touched.

Reads `telextilesd classify --json` output (one press per line, each with
its `source` recording and `coverage`), takes each recording's label (the
directory above the press, as `telextiles-lab sim-presses` writes them)
and, where the recording's press.json carries the simulator's parameters,
its tilt; prints a markdown table of presses, right share and median tilt
per coverage band. Standard library only.

    python3 coverage_table.py NAME=classify.jsonl [NAME=...]
"""
import json
import math
import os
import statistics
import sys

BANDS = [(0.0, 0.3), (0.3, 0.5), (0.5, 0.7), (0.7, 0.9), (0.9, 1.01)]


def rows(path):
    out = []
    with open(path) as f:
        for line in f:
            r = json.loads(line)
            src = r["source"]
            label = os.path.basename(os.path.dirname(src))
            params = {}
            try:
                with open(os.path.join(src, "press.json")) as pj:
                    params = json.load(pj).get("params") or {}
            except OSError:
                pass
            tilt = math.hypot(*params["tilt_deg"]) if "tilt_deg" in params else None
            # p<person>-s<sensor>-<n>, as sim-presses names a press
            who = os.path.basename(src).rsplit("-", 1)[0]
            out.append((r.get("coverage"), r.get("textile") == label, tilt, params, who))
    return out


# What the simulator drew for each press, banded: accuracy against each.
FACTORS = [
    ("tilt (°)", lambda p: math.hypot(*p["tilt_deg"]), [0, 1, 2, 3, 5, 90]),
    ("force (N)", lambda p: p["force_n"], [0, 3, 4, 5, 6, 100]),
    ("slip (mm)", lambda p: math.hypot(*p["slip_mm"]), [0, 0.2, 0.4, 0.6, 0.8, 10]),
    ("wobble", lambda p: p["wobble"], [0, 0.08, 0.12, 0.16, 1]),
]


def factor_table(name, data):
    if not data:
        return
    print(f"\n| {name}: person and unit | presses | right |\n|---|---:|---:|")
    for who in sorted({d[4] for d in data}):
        group = [d for d in data if d[4] == who]
        right = 100.0 * sum(d[1] for d in group) / len(group)
        print(f"| {who} | {len(group)} | {right:.1f} % |")
    if not all(d[3] for d in data):
        return
    print(f"\n| {name}: factor | band | presses | right |\n|---|---|---:|---:|")
    for fname, get, edges in FACTORS:
        for lo, hi in zip(edges[:-1], edges[1:]):
            band = [d for d in data if lo <= get(d[3]) < hi]
            if band:
                right = 100.0 * sum(d[1] for d in band) / len(band)
                print(f"| {fname} | {lo}–{hi} | {len(band)} | {right:.1f} % |")


def main():
    print("| set | coverage | presses | right | median tilt (°) |")
    print("|---|---|---:|---:|---:|")
    for arg in sys.argv[1:]:
        name, path = arg.split("=", 1)
        data = [d for d in rows(path) if d[0] is not None]
        for lo, hi in BANDS:
            band = [d for d in data if lo <= d[0] < hi]
            if not band:
                continue
            right = 100.0 * sum(d[1] for d in band) / len(band)
            tilts = [d[2] for d in band if d[2] is not None]
            tilt = f"{statistics.median(tilts):.1f}" if tilts else "-"
            label = f"{100 * lo:.0f}–{min(100, 100 * hi):.0f} %"
            print(f"| {name} | {label} | {len(band)} | {right:.1f} % | {tilt} |")
        partial = [d for d in data if d[0] < 0.5]
        full = [d for d in data if d[0] >= 0.5]
        for what, part in (("below 50 %", partial), ("50 % or more", full)):
            if part:
                right = 100.0 * sum(d[1] for d in part) / len(part)
                print(f"| {name} | **{what}** | {len(part)} | {right:.1f} % | |")
        tilted = [d for d in data if d[2] is not None]
        if len(tilted) > 2:
            cov = [d[0] for d in tilted]
            til = [d[2] for d in tilted]
            print(f"| {name} | correlation of coverage with tilt: {statistics.correlation(cov, til):.2f} | {len(tilted)} | | |")
    for arg in sys.argv[1:]:
        name, path = arg.split("=", 1)
        factor_table(name, rows(path))


if __name__ == "__main__":
    main()
