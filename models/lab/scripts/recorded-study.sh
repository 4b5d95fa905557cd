#!/usr/bin/env bash
# The study on recorded presses run on a simulated recorded set: the
# figures of docs/recording.md, "The study on your own recordings".
#
#   bash models/lab/scripts/recorded-study.sh [DIR]
#
# DIR (default target/telextiles-lab/simrec) gets recordings/ (72 simulated
# hand-held presses, 12 textiles x 6, by three people on three sensor units
# with different backgrounds, about 1.3 GB of PNG), study-k3/ (3 presses
# per textile build the index) and study-lopo/ (leave one press out). About
# 5 minutes on 2 cores. The latency columns are wall-clock medians: run it
# on a quiet machine.
set -euo pipefail
cd "$(dirname "$0")/../../.."
DIR=${1:-target/telextiles-lab/simrec}
cargo build -p telextiles-lab
LAB=target/debug/telextiles-lab
# shellcheck source=models/lab/scripts/sets.sh
source models/lab/scripts/sets.sh
$LAB sim-presses --out "$DIR/recordings" "${SIMREC[@]}"
for split in "--index-presses 3:study-k3" "--split lopo:study-lopo"; do
    # shellcheck disable=SC2086
    $LAB bench --source "presses:$DIR/recordings" ${split%%:*} \
        --model shipped=models/encoder.onnx --time-threads 1 --runs 100 \
        --out "$DIR/${split##*:}" > /dev/null
    echo "wrote $DIR/${split##*:}/report.md"
done
