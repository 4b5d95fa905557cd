#!/usr/bin/env bash
# The distance an index learns from its own presses (`telextilesd index
# build --presses`, within-fabric whitening): the study on recorded presses
# with and without it, on the three simulated recorded sets of
# recorded-sets.sh (c2hand is the set the shrinkage 0.5 was chosen on;
# nothing of c2g2hand was seen while choosing). The figures of
# docs/recording.md, "A distance learned from your presses".
#
#   bash models/lab/scripts/metric-study.sh
#
# Reports go to docs/bench-v2/metric-recorded/<set>-<split>-<distance>/.
# About 40 minutes on 2 cores, most of it leaving one press out with a
# metric learned again for every query.
set -euo pipefail
cd "$(dirname "$0")/../../.."
# shellcheck source=recorded-sets.sh
. models/lab/scripts/recorded-sets.sh
for set in simrec/recordings c2hand c2g2hand; do
    name=${set%%/*}
    for split in "--index-presses 3:k3" "--split lopo:lopo"; do
        for distance in ":cosine" "--index-metric:metric"; do
            # shellcheck disable=SC2086
            study "docs/bench-v2/metric-recorded/$name-${split##*:}-${distance##*:}" \
                --source "presses:$T/$set" ${split%%:*} ${distance%%:*}
        done
    done
done
