#!/usr/bin/env bash
# One node on sled against one node on PostgreSQL, interleaved, with the
# PostgreSQL WAL bytes per edit.
# Usage: scripts/pg_bench.sh BOTS DURATION ROUNDS
#        scripts/pg_bench.sh --help
# Each round runs scripts/bots_bench.sh (release binaries, --verify
# modified, the metrics line on) on sled, then on a new PostgreSQL
# database, and prints one more JSON line: the WAL bytes the run wrote
# (pg_wal_lsn_diff), the edits logged, and their ratio. PostgreSQL 15 is
# Debian's (STRATA_PG_BIN, default /usr/lib/postgresql/15/bin), started
# once with initdb and pg_ctl in PG_BENCH_DIR (default /tmp/strata-pg-bench)
# on 127.0.0.1:PG_BENCH_PORT (default 55432), as `nobody` when run as root,
# and left running for the next call (stop it with pg_ctl -D DIR/data stop).
set -euo pipefail
if [ "${1:-}" = -h ] || [ "${1:-}" = --help ]; then
    sed -n '2,/^set -euo/{/^set -euo/d; s/^# \{0,1\}//; p}' "$0"
    exit 0
fi
cd "$(dirname "$0")/.."
bots=${1:?bots}; duration=${2:?duration}; rounds=${3:-1}
pg_bin=${STRATA_PG_BIN:-/usr/lib/postgresql/15/bin}
dir=${PG_BENCH_DIR:-/tmp/strata-pg-bench}
port=${PG_BENCH_PORT:-55432}
as_pg=()
if [ "$(id -u)" = 0 ]; then as_pg=(runuser -u nobody --); fi
sql() { "$pg_bin/psql" -h 127.0.0.1 -p "$port" -U strata -d "$1" -Atc "$2"; }
if ! "$pg_bin/pg_isready" -h 127.0.0.1 -p "$port" -q 2>/dev/null; then
    rm -rf "$dir"; mkdir -p "$dir"
    if [ "$(id -u)" = 0 ]; then chown nobody "$dir"; fi
    "${as_pg[@]}" "$pg_bin/initdb" -D "$dir/data" -U strata -A trust > /dev/null
    "${as_pg[@]}" "$pg_bin/pg_ctl" -D "$dir/data" -l "$dir/log" -w \
        -o "-p $port -k $dir -c listen_addresses=127.0.0.1 -c max_connections=300" start > /dev/null
fi
for r in $(seq 1 "$rounds"); do
    echo "== round $r sled"
    BENCH_METRICS_PORT=${BENCH_METRICS_PORT:-19464} \
        scripts/bots_bench.sh "$bots" "$duration" --verify modified
    db="bench_$$_$r"
    "$pg_bin/createdb" -h 127.0.0.1 -p "$port" -U strata "$db"
    lsn0=$(sql "$db" "SELECT pg_current_wal_lsn()")
    echo "== round $r postgres"
    BENCH_METRICS_PORT=${BENCH_METRICS_PORT:-19464} BENCH_SERVER_TOML="$(printf '[store]\nbackend = "postgres"\n[store.postgres]\nurl = "host=127.0.0.1 port=%s user=strata dbname=%s"\n' "$port" "$db")" \
        scripts/bots_bench.sh "$bots" "$duration" --verify modified
    lsn1=$(sql "$db" "SELECT pg_current_wal_lsn()")
    wal=$(sql "$db" "SELECT pg_wal_lsn_diff('$lsn1', '$lsn0')::bigint")
    edits=$(sql "$db" "SELECT count(*) FROM edit_log")
    echo "{\"wal_bytes\":$wal,\"logged_edits\":$edits,\"wal_bytes_per_edit\":$(( wal / (edits > 0 ? edits : 1) ))}"
done
