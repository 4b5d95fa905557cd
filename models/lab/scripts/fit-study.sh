#!/usr/bin/env bash
# The fitted metric against plain cosine, as an owner would build and use an
# index (docs/studies/2026-12-04-fitted-metric.md). From the repository root:
#
#   bash models/lab/scripts/fit-study.sh
#
# Renders (or reuses) three simulated sets of 16 fabrics, hand-held, whose
# index presses and queries come from what no part of the pipeline was
# chosen on: catalogue 2's second texture generator, catalogue 1 on held-out
# sensor units, catalogue 2 hand-held by held-out people. Index presses by
# some people on some units; queries (3 per fabric) and unseen fabrics
# (8 x 2) by other people on another unit. For 3 and 5 index presses per
# fabric it builds three indexes -- plain (the encoder alone, cosine), fit
# (the encoder alone, the fit chosen on the presses) and auto (features and
# fit chosen on the presses) -- classifies the
# queries and the unseen presses against each, and prints the tables the
# study quotes: index build's choice among the fits, then classify's
# decisions (index_table.py). About 25 minutes on 2 cores, most of it
# rendering; 2.5 GB under target/fit-study.
set -euo pipefail
# TELEXTILESD=path: use that build instead (the dev profile's binary
# decides the same, a little slower).
BIN=${TELEXTILESD:-target/release/telextilesd}
[ -n "${TELEXTILESD:-}" ] || cargo build --release -p telextilesd
D=${FIT_DIR:-target/fit-study}
mkdir -p "$D"

. models/lab/scripts/held-out-sets.sh
held_out_sets

args=()
for set in c2g2 c1units c2hand; do
    cat=1
    [ "$set" = c1units ] || cat=2
    for n in 3 5; do
        dir="$D/$set/index"
        [ "$n" = 5 ] || dir="$D/$set/index3"
        # plain: the encoder alone, cosine (the default of `index build`
        # after this study); fit: the encoder alone, the fit chosen on the
        # presses; auto: features and fit chosen on the presses.
        for variant in plain fit auto; do
            case $variant in
                plain) opts=(--features encoder --fit cosine) ;;
                fit) opts=(--features encoder --fit auto) ;;
                auto) opts=(--features auto --fit auto) ;;
            esac
            idx="$D/$set-$n-$variant.tlxi"
            echo "== $set, $n index presses per fabric, $variant (${opts[*]:-defaults})" >&2
            "$BIN" index build --model models/encoder.onnx --presses "$dir" --catalogue "$cat" \
                "${opts[@]}" -o "$idx" > "$D/$set-$n-$variant.build.txt"
            grep -E "^features and distance|^    |^self-check|^wrote" "$D/$set-$n-$variant.build.txt" >&2 || true
            fit=$variant
            for q in queries unseen; do
                "$BIN" classify --index "$idx" --press "$D/$set/$q" --json \
                    > "$D/$set-$n-$fit-$q.jsonl" 2>/dev/null
                args+=("$set/$n/$fit:$q=$D/$set-$n-$fit-$q.jsonl")
            done
        done
    done
done
python3 models/lab/scripts/index_table.py "${args[@]}"

# The first decision against time: the default index of 3 presses per
# fabric, its queries decided with the commit margin at each value (the
# leader's lead over the runner-up that commits at once; 2: always wait
# `confirm_ms`).
margins=()
for set in c2g2 c1units c2hand; do
    for m in 0.02 0.04 0.08 0.16 0.32 2; do
        out="$D/$set-3-auto-m$m.jsonl"
        "$BIN" classify --index "$D/$set-3-auto.tlxi" --press "$D/$set/queries" --json \
            --commit-margin "$m" > "$out" 2>/dev/null
        margins+=("$set/3/auto:margin $m=$out")
    done
done
echo
python3 models/lab/scripts/index_table.py "${margins[@]}"
