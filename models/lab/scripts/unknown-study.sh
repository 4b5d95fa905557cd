#!/usr/bin/env bash
# The unknown-textile flag on an open set: the decider's fixed distance
# against a distance each index calibrates on its own presses (`telextilesd
# index build --presses --unknown-quantile Q`), on the three simulated
# recorded sets of recorded-sets.sh, with cosine distance and with the
# learned one. The figures of docs/recording.md, "Telling a fabric the
# index does not have".
#
#   bash models/lab/scripts/unknown-study.sh
#   K=5 bash models/lab/scripts/unknown-study.sh   # 5 index presses per textile
#
# Each query press is decided twice: against the study's index (its
# textile is known: a flag is a false alarm) and against the index of the
# other textiles (a flag is a detection). Split: the first K presses
# (default 3) of each textile build the index. Reports go to
# docs/bench-v2/unknown-recorded/<set>-k<K>-<distance>/. About 15 minutes
# on 2 cores with the sets already written.
set -euo pipefail
K=${K:-3}
cd "$(dirname "$0")/../../.."
# shellcheck source=recorded-sets.sh
. models/lab/scripts/recorded-sets.sh
for set in c2hand c2g2hand simrec/recordings; do
    name=${set%%/*}
    for distance in ":cosine" "--index-metric:metric"; do
        # shellcheck disable=SC2086
        study "docs/bench-v2/unknown-recorded/$name-k$K-${distance##*:}" \
            --source "presses:$T/$set" --index-presses "$K" ${distance%%:*} \
            --unknown-quantiles 0.8,0.9,0.95,0.99,1
    done
done
