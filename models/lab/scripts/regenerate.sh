#!/usr/bin/env bash
# Regenerates every figure of the speed-vs-accuracy study (docs/benchmarks.md,
# docs/bench/): trains the encoder variants that are missing (hours: see
# train-variants.sh), makes their int8 versions, then runs
# `telextiles-lab bench` over the classical descriptors, the shipped
# encoder of the previous release, the variants and their int8 versions.
#
#   bash models/lab/scripts/regenerate.sh            # the full study
#   BENCH_ARGS="--quick" bash models/lab/scripts/regenerate.sh   # a smoke run
#
# Run it on a quiet machine: the latency columns are wall-clock medians.
set -euo pipefail
cd "$(dirname "$0")/../../.."
MODELS=target/telextiles-lab/models
bash models/lab/scripts/train-variants.sh "$MODELS"
LAB=target/telextiles-lab/bin/telextiles-lab
cargo build -p telextiles-lab
cp target/debug/telextiles-lab "$LAB"
# The previous default encoder (the MoCo-trained resnet-d1111-w16-s64,
# sha256 f427bd6a...), from git history.
if [ ! -f "$MODELS/w16-s64.onnx" ]; then
    git show 133c90b:models/encoder.onnx > "$MODELS/w16-s64.onnx.tmp"
    mv "$MODELS/w16-s64.onnx.tmp" "$MODELS/w16-s64.onnx"
fi
args=()
for m in w16-s32 w8-s64 w16-s64 r18w16-s64 w32-s64 w16-s96 resnet18-s224; do
    [ -f "$MODELS/$m.onnx" ] || { echo "missing $MODELS/$m.onnx" >&2; exit 1; }
    if [ ! -f "$MODELS/$m-int8.onnx" ]; then
        $LAB quantize --source sim --model "$MODELS/$m.onnx" --out "$MODELS/$m-int8.onnx"
    fi
    args+=(--model "$m=$MODELS/$m.onnx" --model "$m-int8=$MODELS/$m-int8.onnx")
done
# int8 of the shipped descriptor too: ONNX Runtime's quantiser turns its
# weak spectral bins into zeros (log = -inf), so quantize refuses it unless
# told; it goes on the chart to show that, never into models/.
if [ ! -f "$MODELS/fft-c192-bg-int8.onnx" ]; then
    $LAB export-descriptor --kind fft --crop 192 --subtract --out "$MODELS/fft-c192-bg.onnx"
    $LAB quantize --source sim --model "$MODELS/fft-c192-bg.onnx" --out "$MODELS/fft-c192-bg-int8.onnx" \
        --allow-nonfinite
fi
args+=(--model "fft-radial-c192-bg-int8=$MODELS/fft-c192-bg-int8.onnx")
$LAB bench --source sim "${args[@]}" --out docs/bench ${BENCH_ARGS:-}
