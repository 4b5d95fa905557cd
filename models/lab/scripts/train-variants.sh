#!/usr/bin/env bash
# Trains and exports the encoder variants of the speed-vs-accuracy chart
# (docs/benchmarks.md) that are not there yet, on this machine's CPU.
# Each is the shipped recipe (MoCo v2, press instances, queue 512, batch 64,
# seed 0) with one thing changed: width, depth or input size; the paper's
# ResNet-18 at 224 gets as many steps as RESNET18_EPOCHS x 14 (default 5
# epochs, about 2.5 h here).
#
#   bash models/lab/scripts/train-variants.sh [OUT_DIR]
#
# Models land in OUT_DIR (default target/telextiles-lab/models); run
# directories (checkpoints, metrics.jsonl) in target/telextiles-lab/runs.
set -euo pipefail
cd "$(dirname "$0")/../../.."
OUT=${1:-target/telextiles-lab/models}
RUNS=target/telextiles-lab/runs
EPOCHS=${EPOCHS:-80}
RESNET18_EPOCHS=${RESNET18_EPOCHS:-5}
mkdir -p "$OUT" "$RUNS"
cargo build -p telextiles-lab
# A copy, so that rebuilding the lab during the hours of training does not
# change the binary between variants.
LAB=target/telextiles-lab/bin/telextiles-lab
mkdir -p "$(dirname "$LAB")"
cp target/debug/telextiles-lab "$LAB.tmp" && mv "$LAB.tmp" "$LAB"
$LAB cache --source sim
# name arch input epochs
while read -r name arch input epochs; do
    [ -f "$OUT/$name.onnx" ] && { echo "have $OUT/$name.onnx"; continue; }
    run=$RUNS/$name
    resume=""
    [ -e "$run/ckpt/latest" ] && resume="--resume"
    echo "training $name ($arch, input $input, $epochs epochs) $(date -u +%FT%TZ)"
    nice -n 10 $LAB train --source sim --arch "$arch" --input "$input" --crop "$input" \
        --epochs "$epochs" --eval-every 10 --queue 512 --batch 64 --seed 0 --run "$run" $resume
    $LAB export --run "$run" --input "$input" --crop "$input" --out "$OUT/$name.onnx"
    echo "done $name $(date -u +%FT%TZ)"
done <<LIST
w16-s32 resnet-d1111-w16-s32 32 $EPOCHS
w8-s64 resnet-d1111-w8-s64 64 $EPOCHS
r18w16-s64 resnet18-w16-s64 64 $EPOCHS
w32-s64 resnet-d1111-w32-s64 64 $EPOCHS
w16-s96 resnet-d1111-w16-s96 96 $EPOCHS
resnet18-s224 resnet18-w64-s224 224 $RESNET18_EPOCHS
LIST
