#!/bin/bash
# One call on a GPU machine (see README.md): renders the presses with 16
# threads, then trains and scores the CNN. Needs, beside this script,
# `dump_presses` (built here) and the lists of make_specs.py.
set -u
G=$(cd "$(dirname "$0")" && pwd); D=/tmp/presses; mkdir -p "$D"
OUT=${OUT:-$G}
start=$(date +%s)
for s in tr idx qa qb qh; do T=16 "$G/dump_presses" "$D/$s" 2 1 "$G/$s.txt" 2>/dev/null || exit 1; done
for s in idx qa qh; do T=16 "$G/dump_presses" "$D/g2$s" 2 2 "$G/$s.txt" 2>/dev/null || exit 1; done
echo "rendered in $(( $(date +%s) - start )) s"
BUDGET=${BUDGET:-240} PYTHONUNBUFFERED=1 python3 "$G/ceiling.py" "$D" "${STEPS:-6000}" "${BATCH:-192}" "${SIDE:-240}" 2>&1 | tee "$OUT/ceiling.log"
