#!/usr/bin/env bash
# Issue #15's checks on a machine with cores to spare, from prebuilt
# binaries, into one archive (a borrowed machine may return only a few
# files, so everything goes into DEST/device_checks.tgz).
# Usage: scripts/device_checks.sh BIN_DIR DEST [quick]
#        scripts/device_checks.sh --help
# BIN_DIR holds strata-server, strata-admin, strata-bots and the pipeline
# bench's binary named `pipeline` (cargo bench -p strata-server --bench
# pipeline --no-run prints its path; strip them all to carry them).
# DEVICE_DEADLINE_S=N starts no run after N seconds from the script's
# start; the archive is written again after every step, so a call cut off
# by its time limit still leaves what finished.
# In order, each step appending to progress.txt (in the archive):
#   1. the pipeline bench at 1, 2, 1, 2, 4 and 8 workers (5 s each, at
#      most 1024 edits a tick);
#   2. bots_bench.sh runs, server pinned to CPUs 0..K-1 and the bots to
#      the rest, most wanted first: 1000 bots on 2 cores, 3000 on 8 with
#      premesh_threads 1 and 2, 200 bots at view radius 8 on 2 cores, 500
#      on 2, 500 on 2 not editing (`--edit-rate 0`: what players online
#      cost, against the 500-bot run's CPU per edit), 2000 on 4, 1000 on 2
#      with net_threads 1, then 1000 on 2 again, 3000 on 8 with premesh_threads 4, and with net_threads 4;
#      each run keeps its JSON lines, its stderr, its slow-tick lines and
#      the server's last metrics scrape (a tag
#      r<i>_<bots>b_<cores>c_p<premesh>_n<net threads>);
#   3. scaling.csv of every run, and table.md built from it (the columns
#      scaling_table.sh prints).
# `quick` runs each step at a tenth of the bots for a few seconds, on
# CPUs 0 and 1: a check of the script itself on a small machine.
set -uo pipefail
if [ "${1:-}" = -h ] || [ "${1:-}" = --help ]; then
    sed -n '2,/^set -uo/{/^set -uo/d; s/^# \{0,1\}//; p}' "$0"
    exit 0
fi
here=$(cd "$(dirname "$0")" && pwd)
bin=$(cd "${1:?BIN_DIR}" && pwd)
dest=${2:?DEST}
quick=${3:-}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
started=$SECONDS
mkdir -p "$dest"
pack() { # the table of what ran so far, and the archive
    if [ -s "$work/scaling.csv" ]; then
        echo "| bots | server cores | accepted edits/s | ack p50 / p99 ms | broadcast p99 ms | server cores used | server CPU ms/edit | mismatches |" > "$work/table.md"
        echo "|---|---|---|---|---|---|---|---|" >> "$work/table.md"
        tail -n +2 "$work/scaling.csv" | awk -F, '{
            gsub(/"/, "", $3); n = split($3, r, "-"); cores = (n == 2) ? r[2] - r[1] + 1 : 1
            printf "| %d | %d | %.0f | %s / %s | %s | %s | %s | %d |\n",
                $1, cores, ($2 > 0 ? $5 / $2 : 0), $17, $18, $19, $13, $14, $20 }' >> "$work/table.md"
    fi
    tar czf "$dest/device_checks.tgz.part" -C "$work" . && mv "$dest/device_checks.tgz.part" "$dest/device_checks.tgz"
}
log() { echo "$(date +%T) $*" >> "$work/progress.txt"; }
{ nproc; lscpu | grep -E "Model name|NUMA node\(s\)|Thread"; uname -r; free -g | head -2; } \
    > "$work/machine.txt" 2>&1

seconds=5 counts=(1 2 1 2 4 8) duration=20s scale=1
if [ "$quick" = quick ]; then seconds=1 counts=(1 2) duration=2s scale=10; fi
log "pipeline ${counts[*]}"
STRATA_BENCH_EDITS_PER_TICK=1024 STRATA_BENCH_SECONDS=$seconds \
    timeout 300 "$bin/pipeline" "${counts[@]}" > "$work/pipeline.txt" 2>&1
log "pipeline rc=$?"
pack

i=0
run() { # BOTS SERVER_CORES PREMESH_THREADS NET_THREADS [strata-bots args...]
    local bots=$(( $1 / scale )) k=$2 threads=$3 net=$4 cpus bots_cpus tag
    shift 4
    i=$((i + 1))
    if [ -n "${DEVICE_DEADLINE_S:-}" ] && (( SECONDS - started > DEVICE_DEADLINE_S )); then
        log "skip run $i ($bots bots): past DEVICE_DEADLINE_S"
        return
    fi
    cpus="0-$((k - 1))" bots_cpus="$k-$(( $(nproc) - 1 ))"
    if [ "$quick" = quick ]; then cpus=0 bots_cpus=1; fi
    tag="r${i}_${bots}b_${k}c_p${threads}_n${net}"
    log "start $tag"
    BENCH_BIN_DIR="$bin" BENCH_METRICS_PORT=$((9400 + i)) BENCH_LOG="$work/$tag.log" \
        BENCH_METRICS_DUMP="$work/$tag.prom" BENCH_CSV="$work/scaling.csv" \
        BENCH_SERVER_CPUS="$cpus" BENCH_BOT_CPUS="$bots_cpus" \
        BENCH_SERVER_TOML="net_threads = $net"$'\n[engine]\npremesh_threads = '"$threads" \
        timeout 180 "$here/bots_bench.sh" "$bots" "$duration" "$@" \
        > "$work/$tag.json" 2> "$work/$tag.err"
    log "end $tag rc=$?"
    grep "slow tick" "$work/$tag.log" > "$work/$tag.slow"
    rm -f "$work/$tag.log"
    pack
}
run 1000 2 1 0 --verify modified
run 3000 8 1 0 --verify modified
run 3000 8 2 0 --verify modified
run 200 2 1 0 --view-radius 8 --verify modified
run 500 2 1 0 --verify modified
run 500 2 1 0 --verify modified --edit-rate 0
run 2000 4 1 0 --verify modified
run 1000 2 1 1 --verify modified
run 1000 2 1 0 --verify modified
run 3000 8 4 0 --verify modified
run 3000 8 1 4 --verify modified

log done
pack
echo "device_checks: $dest/device_checks.tgz"
