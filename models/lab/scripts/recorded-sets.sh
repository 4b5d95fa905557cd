# Sourced by metric-study.sh and unknown-study.sh (from the repository
# root): builds the lab, writes the three simulated recorded sets under
# target/telextiles-lab/ (presses already there are kept) and the untrained
# whitened spectrum, and defines `study OUT BENCH-ARGS...`, which runs the
# recorded study with the shipped model and that spectrum into OUT.
#
#   simrec/recordings  catalogue 1: 12 textiles x 6 hand-held presses,
#                      people 8-10, units 0, 4, 5 (the set of
#                      docs/recording.md section 4)
#   c2hand             catalogue 2, generator 1: 40 textiles x 8 hand-held
#                      presses, people 8-11, units 0, 4, 5, 6
#   c2g2hand           catalogue 2, generator 2 (the cross-generator
#                      texture model): 20 other textiles x 8 hand-held
#                      presses, people 0, 3, 5, 7, units 1, 7, 8, 9, seed 11
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

study() {
    local out=$1
    shift
    $LAB bench "$@" \
        --model shipped=models/encoder.onnx \
        --model wspec-c240-s120-bg=$M/wspec-c240-s120-bg.onnx \
        --no-descriptors --time-threads 1 --runs 30 --out "$out" > /dev/null
    echo "wrote $out/report.md"
}
