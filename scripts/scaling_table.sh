#!/usr/bin/env bash
# Bots against server cores: one scripts/bots_bench.sh run per pair, the
# server pinned to CPUs 0..K-1 and the bots to the rest, then a Markdown
# table of the runs (issue #15's table).
# Usage: scripts/scaling_table.sh [BOTS_LIST] [SERVER_CORES_LIST] [DURATION] [EXTRA strata-bots ARGS...]
#        defaults: 500,1000,2000,3000  2,4,8  20s  --verify modified
#        scripts/scaling_table.sh --help
# Each run appends a row to SCALING_CSV (default scaling.csv; see
# bots_bench.sh for its columns), and the table covers this call's rows.
# BENCH_BIN_DIR (prebuilt strata-server, strata-admin and strata-bots) and
# the other BENCH_* settings pass through to bots_bench.sh. A pair whose
# server cores leave no CPU for the bots is skipped with a note.
set -euo pipefail
if [ "${1:-}" = -h ] || [ "${1:-}" = --help ]; then
    sed -n '2,/^set -euo/{/^set -euo/d; s/^# \{0,1\}//; p}' "$0"
    exit 0
fi
here=$(cd "$(dirname "$0")" && pwd)
bots_list=${1:-500,1000,2000,3000}
cores_list=${2:-2,4,8}
duration=${3:-20s}
shift $(( $# < 3 ? $# : 3 ))
extra=("$@")
[ ${#extra[@]} -gt 0 ] || extra=(--verify modified)
csv=${SCALING_CSV:-scaling.csv}
for tool in taskset /usr/bin/time curl; do
    command -v "$tool" >/dev/null || { echo "scaling_table: $tool is missing" >&2; exit 1; }
done
cpus=$(nproc)
# This call's rows: after the file's lines, or after the header it writes.
if [ -s "$csv" ]; then first=$(( $(wc -l < "$csv") + 1 )); else first=2; fi
IFS=, read -ra bots_counts <<< "$bots_list"
IFS=, read -ra core_counts <<< "$cores_list"
for bots in "${bots_counts[@]}"; do
    for k in "${core_counts[@]}"; do
        if [ "$k" -ge "$cpus" ]; then
            echo "scaling_table: $k server cores leave none of $cpus for the bots; skipped" >&2
            continue
        fi
        echo "scaling_table: $bots bots, server on CPUs 0-$((k - 1)), bots on $k-$((cpus - 1))" >&2
        BENCH_SERVER_CPUS="0-$((k - 1))" BENCH_BOT_CPUS="$k-$((cpus - 1))" BENCH_CSV="$csv" \
            "$here/bots_bench.sh" "$bots" "$duration" "${extra[@]}" > /dev/null
    done
done
echo "| bots | server cores | accepted edits/s | ack p50 / p99 ms | broadcast p99 ms | server cores used | server CPU ms/edit | mismatches |"
echo "|---|---|---|---|---|---|---|---|"
tail -n +"$first" "$csv" | awk -F, '{
    gsub(/"/, "", $3); n = split($3, r, "-"); cores = (n == 2) ? r[2] - r[1] + 1 : split($3, c, " ")
    printf "| %d | %d | %.0f | %s / %s | %s | %s | %s | %d |\n",
        $1, cores, ($2 > 0 ? $5 / $2 : 0), $17, $18, $19, $13, $14, $20 }'
