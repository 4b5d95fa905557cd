# The held-out simulated sets the studies share (sourced by fit-study.sh and
# felt-study.sh, with BIN and D set). Each set: 16 fabrics; index presses
# (5, and the first 3 as index3) by some people on some units; queries (3
# per fabric) and unseen fabrics (8 x 2) by other people on another unit.

# render SET TEXTILE PERSON UNIT SEED KIND SIMARGS...: one press (hand-held
# when SIMARGS say --no-jig) into $D/SET/KIND/TEXTILE/p<person>-s<unit>-<seed>/
# (kept if there).
render() {
    local set=$1 textile=$2 person=$3 unit=$4 seed=$5 kind=$6
    shift 6
    local out="$D/$set/$kind/$textile/p$person-s$unit-$seed"
    [ -d "$out" ] || "$BIN" sim --textile "$textile" --person "$person" --sensor "$unit" \
        --seed "$seed" "$@" --out "$out" >/dev/null
}

# make_set SET "TEXTILES" "INDEX_PEOPLE" "INDEX_UNITS" "QUERY_PEOPLE" QUERY_UNIT SIMARGS...
make_set() {
    local set=$1 textiles=$2
    local -a ipeople=($3) iunits=($4) qpeople=($5)
    local qunit=$6
    shift 6
    echo "rendering $set" >&2
    for t in $textiles; do
        # INDEX_PRESSES=3: only the three of index3.
        for k in $(seq 0 $((${INDEX_PRESSES:-5} - 1))); do
            render "$set" "$t" "${ipeople[k % ${#ipeople[@]}]}" "${iunits[k % ${#iunits[@]}]}" \
                "$((100 + k))" index "$@"
        done
        for k in 0 1 2; do
            render "$set" "$t" "${qpeople[k % ${#qpeople[@]}]}" "$qunit" "$((200 + k))" queries "$@"
        done
    done
    # UNSEEN=0: no presses of fabrics the index does not hold.
    [ "${UNSEEN:-1}" = 0 ] || for u in U01 U02 U03 U04 U05 U06 U07 U08; do
        for k in 0 1; do
            render "$set" "$u" "${qpeople[k % ${#qpeople[@]}]}" "$qunit" "$((300 + k))" unseen "$@"
        done
    done
    # The 3-press index: the first three of the five (hard links).
    if [ ! -d "$D/$set/index3" ]; then
        mkdir -p "$D/$set/index3.part"
        for t in $textiles; do
            mkdir -p "$D/$set/index3.part/$t"
            for k in 0 1 2; do
                cp -al "$D/$set/index/$t/p${ipeople[k % ${#ipeople[@]}]}-s${iunits[k % ${#iunits[@]}]}-$((100 + k))" \
                    "$D/$set/index3.part/$t/"
            done
        done
        mv "$D/$set/index3.part" "$D/$set/index3"
    fi
}

seq16() { local first=$1 step=$2; for k in $(seq 0 15); do printf 'T%03d ' $((first + step * k)); done; }


# The fitted-metric study's three hand-held sets: catalogue 2's second
# texture generator, catalogue 1 on held-out sensor units, catalogue 2 by
# held-out people.
held_out_sets() {
    make_set c2g2 "$(seq16 41 4)" "0 3" "7 8" "5 7" 9 --catalogue 2 --generator 2 --no-jig
    make_set c1units "$(seq16 5 7)" "8 9" "4" "10" 5 --catalogue 1 --no-jig
    make_set c2hand "$(seq16 2 7)" "8 9" "4 5" "10 11" 6 --catalogue 2 --no-jig
}
