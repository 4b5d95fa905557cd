#!/usr/bin/env bash
# The distance an index learns from its own presses (`telextilesd index
# build --presses`, within-fabric whitening): the study on recorded presses
# with and without it, on three simulated recorded sets. The figures of
# docs/recording.md, "A distance learned from your presses".
#
#   bash models/lab/scripts/metric-study.sh
#
# Sets (under target/telextiles-lab/, written once, kept):
#   simrec/recordings  catalogue 1: 12 textiles x 6 hand-held presses,
#                      people 8-10, units 0, 4, 5 (the set of section 4)
#   c2hand             catalogue 2, generator 1: 40 textiles x 8 hand-held
#                      presses, people 8-11, units 0, 4, 5, 6 (the set the
#                      shrinkage 0.5 was chosen on)
#   c2g2hand           catalogue 2, generator 2 (the cross-generator
#                      texture model): 20 other textiles x 8 hand-held
#                      presses, people 0, 3, 5, 7, units 1, 7, 8, 9, seed 11
#                      (nothing of it was seen while choosing)
# Reports go to docs/bench-v2/metric-recorded/<set>-<split>-<distance>/.
# About 40 minutes on 2 cores, most of it leaving one press out with a
# metric learned again for every query.
set -euo pipefail
cd "$(dirname "$0")/../../.."
cargo build --release -p telextiles-lab
LAB=target/release/telextiles-lab
T=target/telextiles-lab
M=$T/models
$LAB sim-presses --out $T/simrec/recordings --first 12 --presses 6 \
    --sensors 0,4,5 --people 8,9,10 --hand
$LAB sim-presses --out $T/c2hand --catalogue 2 --first 40 --presses 8 \
    --sensors 0,4,5,6 --people 8,9,10,11 --hand
$LAB sim-presses --out $T/c2g2hand --catalogue 2 --generator 2 \
    --textiles "$(seq -f "T%03g" 41 4 119 | paste -sd,)" --presses 8 \
    --sensors 1,7,8,9 --people 0,3,5,7 --hand --seed 11
$LAB export-descriptor --kind wspec --crop 240 --input 120 --subtract \
    --out $M/wspec-c240-s120-bg.onnx
for set in simrec/recordings c2hand c2g2hand; do
    name=${set%%/*}
    for split in "--index-presses 3:k3" "--split lopo:lopo"; do
        for distance in ":cosine" "--index-metric:metric"; do
            # shellcheck disable=SC2086
            $LAB bench --source "presses:$T/$set" ${split%%:*} ${distance%%:*} \
                --model shipped=models/encoder.onnx \
                --model wspec-c240-s120-bg=$M/wspec-c240-s120-bg.onnx \
                --no-descriptors --time-threads 1 --runs 30 \
                --out "docs/bench-v2/metric-recorded/$name-${split##*:}-${distance##*:}" > /dev/null
            echo "wrote docs/bench-v2/metric-recorded/$name-${split##*:}-${distance##*:}/report.md"
        done
    done
done
