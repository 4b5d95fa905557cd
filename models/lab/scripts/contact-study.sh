#!/usr/bin/env bash
# The contact-detector study of docs/benchmarks.md ("The contact detector:
# false presses at rest against time to a right decision"): false presses
# of every candidate detector on simulated idle footage, the decider's
# timing study on both catalogues with each detector the rule can compare,
# and the written rule over them (choice.md, right-at-100ms.svg).
# About an hour on a 2-core machine (the idle study 10 min, each timing
# study 2-5 min). Run from the repository root after
# `cargo build --release -p telextiles-lab`.
set -euo pipefail
cd "$(dirname "$0")/../../.."
LAB=target/release/telextiles-lab
D=docs/bench-v2/contact-detector
$LAB contact-idle --units 1:0,4,5 --units 2:0,4,5,9 --seconds 150 --stress 0,0.25,0.5 --out $D/idle
# enter threshold, frames in a row, p(lain) or g(ain taken out)
for v in "0.35 3 g" "0.35 2 g" "0.2 2 g" "0.1 2 g" "0.35 2 p" "0.2 3 p" "0.2 2 p" "0.1 3 p"; do
    set -- $v
    gain="--contact-gain false"
    [ "$3" = g ] && gain="--contact-gain true"
    $LAB decider-timing --catalogue 1 --contact-enter "$1" --contact-frames "$2" $gain \
        --out $D/timing/v1-e$1-f$2-$3
    $LAB decider-timing --catalogue 2 --heldout-people 9 --people 3 --contact-enter "$1" \
        --contact-frames "$2" $gain --out $D/timing/v2-e$1-f$2-$3
done
# The detector before (0.35 DN x 3, plain) is the decider-commit-margin study's.
T=()
for f in $D/timing/*/timing.json; do T+=(--timing "$f"); done
$LAB contact-choose --idle $D/idle/idle.json \
    --timing docs/bench-v2/decider-commit-margin/v1/timing.json \
    --timing docs/bench-v2/decider-commit-margin/v2/timing.json "${T[@]}" --out $D
