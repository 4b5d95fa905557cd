# Sourced by metric-study.sh and unknown-study.sh (from the repository
# root): builds the lab, writes the three simulated recorded sets under
# target/telextiles-lab/ (presses already there are kept) and the untrained
# whitened spectrum, and defines `study OUT BENCH-ARGS...`, which runs the
# recorded study with the shipped model and that spectrum into OUT.
#
#   simrec/recordings  SIMREC of sets.sh (catalogue 1, 12 x 6 hand-held)
#   c2hand             C2HAND (catalogue 2, 40 x 8 hand-held)
#   c2g2hand           C2G2HAND (catalogue 2, generator 2, 20 x 8 hand-held)
# shellcheck source=models/lab/scripts/sets.sh
source models/lab/scripts/sets.sh
cargo build --release -p telextiles-lab
LAB=target/release/telextiles-lab
T=target/telextiles-lab
M=$T/models
$LAB sim-presses --out $T/simrec/recordings "${SIMREC[@]}"
$LAB sim-presses --out $T/c2hand "${C2HAND[@]}"
$LAB sim-presses --out $T/c2g2hand "${C2G2HAND[@]}"
$LAB export-descriptor --kind wspec --crop 240 --input 120 --subtract \
    --out $M/wspec-c240-s120-bg.onnx

study() {
    local out=$1
    shift
    $LAB bench "$@" \
        --model shipped=models/encoder.onnx \
        --model wspec-c240-s120-bg=$M/wspec-c240-s120-bg.onnx \
        --no-descriptors --time-threads 1 --runs 30 --out "$out" > /dev/null
    echo "wrote $out/report.md"
}
