#!/usr/bin/env bash
# The contact-detector study of docs/benchmarks.md ("The contact detector:
# false presses at rest against time to a right decision"): false presses
# of every candidate detector on simulated idle footage, the decider's
# timing study on both catalogues with each detector the rule can compare,
# and the written rule over them (choice.md, right-at-100ms.svg).
# About an hour on a 2-core machine (the idle study 4-10 min, each timing
# study 1.5-5 min). Run from the repository root after
# `cargo build --release -p telextiles-lab`.
set -euo pipefail
cd "$(dirname "$0")/../../.."
LAB=target/release/telextiles-lab
D=docs/bench-v2/contact-detector
$LAB contact-idle --units 1:0,4,5 --units 2:0,4,5,9 --seconds 150 --stress 0,0.25,0.5 --out $D/idle
# enter threshold, frames in a row, p(lain) or g(ain taken out), and the
# tile scored (blocks of 4 px a side; 0 = the whole frame)
for v in "0.35 3 g 0" "0.35 2 g 0" "0.2 2 g 0" "0.1 2 g 0" "0.35 2 p 0" "0.2 3 p 0" "0.2 2 p 0" "0.1 3 p 0" \
    "0.6 2 g 10" "0.8 2 g 10" "0.47 2 g 20"; do
    set -- $v
    gain="--contact-gain false"
    [ "$3" = g ] && gain="--contact-gain true"
    tile="" name="e$1-f$2-$3"
    if [ "$4" != 0 ]; then tile="--contact-tile $4" name="$name-t$4"; fi
    $LAB decider-timing --catalogue 1 --contact-enter "$1" --contact-frames "$2" $gain $tile \
        --out $D/timing/v1-$name
    $LAB decider-timing --catalogue 2 --heldout-people 9 --people 3 --contact-enter "$1" \
        --contact-frames "$2" $gain $tile --out $D/timing/v2-$name
done
# The detector before (0.35 DN x 3, plain) is the decider-commit-margin study's.
T=()
for f in $D/timing/*/timing.json; do T+=(--timing "$f"); done
$LAB contact-choose --idle $D/idle/idle.json \
    --timing docs/bench-v2/decider-commit-margin/v1/timing.json \
    --timing docs/bench-v2/decider-commit-margin/v2/timing.json "${T[@]}" --out $D
