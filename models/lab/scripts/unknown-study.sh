#!/usr/bin/env bash
# The unknown-textile flag on an open set: the decider's fixed distance
# against a distance each index calibrates on its own presses (`telextilesd
# index build --presses --unknown-quantile Q`), on the three simulated
# recorded sets of metric-study.sh (written there if missing), with cosine
# distance and with the learned one. The figures of docs/recording.md,
# "Telling a fabric the index does not have".
#
#   bash models/lab/scripts/unknown-study.sh
#
# Each query press is decided twice: against the study's index (its
# textile is known: a flag is a false alarm) and against the index of the
# other textiles (a flag is a detection). Split: the first 3 presses of
# each textile build the index. Reports go to
# docs/bench-v2/unknown-recorded/<set>-k3-<distance>/. About 15 minutes on
# 2 cores with the sets already written.
set -euo pipefail
cd "$(dirname "$0")/../../.."
cargo build --release -p telextiles-lab
LAB=target/release/telextiles-lab
T=target/telextiles-lab
M=$T/models
[ -d $T/simrec/recordings ] || $LAB sim-presses --out $T/simrec/recordings --first 12 --presses 6 \
    --sensors 0,4,5 --people 8,9,10 --hand
[ -d $T/c2hand ] || $LAB sim-presses --out $T/c2hand --catalogue 2 --first 40 --presses 8 \
    --sensors 0,4,5,6 --people 8,9,10,11 --hand
[ -d $T/c2g2hand ] || $LAB sim-presses --out $T/c2g2hand --catalogue 2 --generator 2 \
    --textiles "$(seq -f "T%03g" 41 4 119 | paste -sd,)" --presses 8 \
    --sensors 1,7,8,9 --people 0,3,5,7 --hand --seed 11
[ -f $M/wspec-c240-s120-bg.onnx ] || $LAB export-descriptor --kind wspec --crop 240 --input 120 \
    --subtract --out $M/wspec-c240-s120-bg.onnx
for set in c2hand c2g2hand simrec/recordings; do
    name=${set%%/*}
    for distance in ":cosine" "--index-metric:metric"; do
        # shellcheck disable=SC2086
        $LAB bench --source "presses:$T/$set" --index-presses 3 ${distance%%:*} \
            --unknown-quantiles 0.8,0.9,0.95,0.99,1 \
            --model shipped=models/encoder.onnx \
            --model wspec-c240-s120-bg=$M/wspec-c240-s120-bg.onnx \
            --no-descriptors --time-threads 1 --runs 30 \
            --out "docs/bench-v2/unknown-recorded/$name-k3-${distance##*:}" > /dev/null
        echo "wrote docs/bench-v2/unknown-recorded/$name-k3-${distance##*:}/report.md"
    done
done
