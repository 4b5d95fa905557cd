# The simulated recorded sets of the studies, defined once: sourced by
# recorded-sets.sh, recorded-study.sh and classify-settings.sh, which pass
# these arrays to `telextiles-lab sim-presses` (a set already written is
# kept, so the scripts share presses only if they agree on them here).
#
#   SIMREC    catalogue 1: 12 textiles x 6 hand-held presses, people 8-10,
#             units 0, 4, 5 (the set of docs/recording.md section 4)
#   C2HAND    catalogue 2, generator 1: 40 textiles x 8 hand-held presses,
#             people 8-11, units 0, 4, 5, 6
#   C2G2HAND  catalogue 2, generator 2 (the cross-generator texture model):
#             20 other textiles x 8 hand-held presses, people 0, 3, 5, 7,
#             units 1, 7, 8, 9, seed 11
# shellcheck disable=SC2034  # used by the scripts that source this one
SIMREC=(--first 12 --presses 6 --sensors 0,4,5 --people 8,9,10 --hand)
# shellcheck disable=SC2034
C2HAND=(--catalogue 2 --first 40 --presses 8 --sensors 0,4,5,6 --people 8,9,10,11 --hand)
# shellcheck disable=SC2034
C2G2HAND=(--catalogue 2 --generator 2 --textiles "$(seq -f "T%03g" 41 4 119 | paste -sd,)"
    --presses 8 --sensors 1,7,8,9 --people 0,3,5,7 --hand --seed 11)
