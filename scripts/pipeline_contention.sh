#!/usr/bin/env bash
# Is the pipeline bench's CPU per edit the code's or the machine's?
# Runs the bench's binary with 1 worker alone, with 2 workers alone, and
# as COPIES independent 1-worker processes at once (nothing shared but the
# machine), in the order 1, 2, copies, 1, 2, copies. If one worker's CPU
# per edit rises as much beside another process as beside a second worker
# of its own, the rise is the machine's (shared cores, caches, memory,
# clock), not contention inside the server.
# Usage: scripts/pipeline_contention.sh PIPELINE_BIN [COPIES...] > out.txt
#        scripts/pipeline_contention.sh --help
# Default COPIES: 2 4. STRATA_BENCH_SECONDS (default 5) and
# STRATA_BENCH_EDITS_PER_TICK (default 1024) go to every run. Prints each
# run's table rows, tagged with the run's name and copy number.
set -uo pipefail
if [ "${1:-}" = -h ] || [ "${1:-}" = --help ]; then
    sed -n '2,/^set -uo/{/^set -uo/d; s/^# \{0,1\}//; p}' "$0"
    exit 0
fi
bin=${1:?PIPELINE_BIN}
shift
copies=("$@")
[ ${#copies[@]} -gt 0 ] || copies=(2 4)
export STRATA_BENCH_SECONDS=${STRATA_BENCH_SECONDS:-5}
export STRATA_BENCH_EDITS_PER_TICK=${STRATA_BENCH_EDITS_PER_TICK:-1024}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

rows() { # FILE TAG: the table's rows, tagged
    grep -E '^\| [0-9]+ \|' "$1" | sed "s/^/$2 /"
}
alone() { # WORKERS
    timeout 120 "$bin" "$1" > "$work/alone" 2>&1
    [ -n "${header:-}" ] || { header=1; grep -m1 '^| workers' "$work/alone" | sed 's/^/run /'; }
    rows "$work/alone" "alone_w$1"
}
together() { # COPIES
    local n=$1 k pids=()
    for k in $(seq "$n"); do
        timeout 120 "$bin" 1 > "$work/copy$k" 2>&1 &
        pids+=($!)
    done
    wait "${pids[@]}"
    for k in $(seq "$n"); do rows "$work/copy$k" "copies${n}_#$k"; done
}
for pass in 1 2; do
    echo "# pass $pass"
    alone 1
    alone 2
    for n in "${copies[@]}"; do together "$n"; done
done
