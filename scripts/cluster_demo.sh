#!/usr/bin/env bash
# Three strata-server nodes sharing one world on PostgreSQL, bots on each
# walking across region borders, one node SIGKILLed halfway.
# Usage: scripts/cluster_demo.sh [BOTS_PER_NODE] [DURATION_S]
#        scripts/cluster_demo.sh --help
# Defaults: 4 bots per node, 20 seconds of editing (1 edit per bot per s).
#
# - Builds the release binaries (CLUSTER_DEMO_PROFILE=debug: the debug ones).
# - Starts PostgreSQL 15 from Debian's binaries (STRATA_PG_BIN, default
#   /usr/lib/postgresql/15/bin) with initdb and pg_ctl in a temp dir on
#   127.0.0.1 (as `nobody` when run as root), stopped at the end.
# - Starts node-0, node-1 and node-2 ([cluster], lease 2 s, renewed every
#   0.4 s, one auth secret and certificate shared), each with bots whose
#   square straddles a region corner (regions of 8 chunks, 256 voxels), so
#   they walk from one region into another; each node holds the regions its
#   players edit. node-0's and node-1's bots share one corner: a bot whose
#   edit lands in the other node's region moves there with its ticket
#   (`strata-bots --follow-owners`), and node-1's bots on node-0 come back
#   when node-0 dies.
# - Halfway, SIGKILLs node-0 and times how long until node-1 or node-2
#   holds every region node-0 held (they adopt what they find expired).
# - At the end: `strata-admin verify-acks` of every node's ack log against
#   PostgreSQL (node-0's included) and `strata-admin check`.
# The last line is JSON:
#   {"nodes":3,"edits_accepted":N,"acked_lost":N,"replica_mismatches":N,
#    "border_crossings":N,"takeover_ms":N}
# and then handoffs (bots moved to another node), ack_p99_ms and
# broadcast_p99_ms (the worse of the survivors' fleets), and
# commit_p50_ms/commit_p99_ms: PostgreSQL group-commit latency per tick
# (`strata_flush_seconds`, the worse survivor, from its /metrics on port
# CLUSTER_DEMO_PG_PORT + 1 + node). edits_accepted counts node-0's acks until its death and the
# survivors' summaries; the other figures are the survivors' bots' (node-0's
# bots lose their server). Exits non-zero if an
# acknowledged edit is missing, a replica differs, or check fails.
set -euo pipefail
if [ "${1:-}" = -h ] || [ "${1:-}" = --help ]; then
    sed -n '2,/^set -euo/{/^set -euo/d; s/^# \{0,1\}//; p}' "$0"
    exit 0
fi
cd "$(dirname "$0")/.."
bots=${1:-4}; duration=${2:-20}
profile=${CLUSTER_DEMO_PROFILE:-release}
pg_bin=${STRATA_PG_BIN:-/usr/lib/postgresql/15/bin}
port=${CLUSTER_DEMO_PG_PORT:-55433}
target=${CARGO_TARGET_DIR:-target}/$profile
if [ "$profile" = release ]; then
    cargo build --release --locked -q -p strata-server -p strata-client-sim --bins
else
    cargo build --locked -q -p strata-server -p strata-client-sim --bins
fi
dir=$(mktemp -d /tmp/strata-cluster-demo.XXXXXX)
as_pg=()
if [ "$(id -u)" = 0 ]; then as_pg=(runuser -u nobody --); chown nobody "$dir"; fi
pids=()
cleanup() {
    kill "${pids[@]}" 2>/dev/null || true
    wait 2>/dev/null || true
    "${as_pg[@]}" "$pg_bin/pg_ctl" -D "$dir/pg" -m immediate stop > /dev/null 2>&1 || true
    [ -n "${CLUSTER_DEMO_KEEP:-}" ] || rm -rf "$dir"
}
trap cleanup EXIT
"${as_pg[@]}" "$pg_bin/initdb" -D "$dir/pg" -U strata -A trust > /dev/null
"${as_pg[@]}" "$pg_bin/pg_ctl" -D "$dir/pg" -l "$dir/pg.log" -w \
    -o "-p $port -k $dir -c listen_addresses=127.0.0.1" start > /dev/null
"$pg_bin/createdb" -h 127.0.0.1 -p "$port" -U strata world
store=$(printf '[store]\nbackend = "postgres"\n[store.postgres]\nurl = "host=127.0.0.1 port=%s user=strata dbname=world"\n' "$port")

# Bot squares straddle region corners: (256, 256) for node-0's and
# node-1's bots, (-1280, 256) for node-2's; half the square on each side.
side=$(awk -v b="$bots" 'BEGIN { s = int(sqrt(b)); if (s * s < b) s++; print s * 24 }')
corners=(256 256 -1280)
addrs=()
for i in 0 1 2; do
    mkdir -p "$dir/node-$i"
    if [ "$i" -gt 0 ]; then
        for f in auth.secret cert.der key.der; do cp "$dir/node-0/$f" "$dir/node-$i/$f"; done
    fi
    # All bots come from one address: room for them in the admission limits.
    printf '%s\n[server]\nlisten = "127.0.0.1:0"\nmax_connections = %s\nmax_handshakes = %s\nmax_handshakes_per_address = %s\n[metrics]\nlisten = "127.0.0.1:%s"\n[cluster]\nnode_id = "node-%s"\nlease_ms = 2000\nrenew_ms = 400\n' \
        "$store" $((bots + 64)) $((bots + 64)) $((bots + 64)) $((port + 1 + i)) "$i" > "$dir/node-$i/strata.toml"
    "$target/strata-server" --config "$dir/node-$i/strata.toml" --data-dir "$dir/node-$i" \
        > "$dir/node-$i.out" 2> "$dir/node-$i.log" &
    pids+=($!)
    for _ in $(seq 300); do grep -q listening "$dir/node-$i.out" 2>/dev/null && break; sleep 0.1; done
    addrs+=("$(grep -oE '127\.0\.0\.1:[0-9]+' "$dir/node-$i.out" | head -1)")
    [ -n "${addrs[$i]}" ] || { echo "node-$i did not start: $(tail -5 "$dir/node-$i.log")" >&2; exit 1; }
done
sql() { "$pg_bin/psql" -h 127.0.0.1 -p "$port" -U strata -d world -Atc "$1"; }
fleet=()
for i in 0 1 2; do
    origin="$(( ${corners[$i]} - side / 2 )),$(( 256 - side / 2 ))"
    RUST_LOG=${CLUSTER_DEMO_BOTS_LOG:-warn} "$target/strata-bots" --server "${addrs[$i]}" --data-dir "$dir/node-$i" \
        --bots "$bots" --duration "${duration}s" --edit-rate 1 --area-origin "$origin" \
        --verify modified --follow-owners --player-prefix "n$i-bot" --ack-log "$dir/acks-$i.jsonl" --json \
        > "$dir/bots-$i.json" 2> "$dir/bots-$i.log" &
    fleet+=($!); pids+=($!)
    if [ "$i" = 0 ]; then
        # node-0 first holds a region at the shared corner, so there is
        # something to take over when it dies.
        for _ in $(seq 600); do
            [ "$(sql "SELECT count(*) FROM regions WHERE owner = 'node-0'")" != 0 ] && break
            sleep 0.05
        done
    fi
done
echo "3 nodes at ${addrs[*]}, $bots bots each; node-0 dies in $(( duration / 2 + 2 )) s" >&2

sleep $(( duration / 2 + 2 ))
held=$(sql "SELECT region_x || ',' || region_z FROM regions WHERE owner = 'node-0' ORDER BY 1")
disown "${pids[0]}"   # no "Killed" line from the shell
kill -KILL "${pids[0]}"
t0=$(date +%s%N)
disown "${fleet[0]}"
kill -KILL "${fleet[0]}" 2>/dev/null || true   # its node is gone
takeover_ms=null
if [ -n "$held" ]; then
    list=$(echo "$held" | sed "s/^/'/; s/$/'/" | paste -sd,)
    for _ in $(seq 600); do
        left=$(sql "SELECT count(*) FROM regions WHERE region_x || ',' || region_z IN ($list) \
                    AND owner NOT IN ('node-1', 'node-2')")
        if [ "$left" = 0 ]; then takeover_ms=$(( ($(date +%s%N) - t0) / 1000000 )); break; fi
        sleep 0.02
    done
fi
wait "${fleet[1]}" "${fleet[2]}" || true

field() { grep -oE "\"$2\":[-0-9.eE+]+" "$1" | head -1 | cut -d: -f2; }
# p99 of the named latency object in a summary.
p99() { grep -oE "\"$2\":\{[^}]*\}" "$1" | grep -oE '"p99":[0-9.eE+-]+' | cut -d: -f2; }
edits=$(wc -l < "$dir/acks-0.jsonl"); lost=0; mismatches=0; crossings=0; handoffs=0; ack99=0; bc99=0
for i in 1 2; do
    f="$dir/bots-$i.json"
    [ -s "$f" ] || { echo "node-$i's bots printed no summary: $(tail -5 "$dir/bots-$i.log")" >&2; exit 1; }
    edits=$(( edits + $(field "$f" edits_accepted) ))
    mismatches=$(( mismatches + $(field "$f" replica_mismatches) + $(field "$f" mesh_mismatches) ))
    crossings=$(( crossings + $(field "$f" region_crossings) ))
    handoffs=$(( handoffs + $(field "$f" handoffs) ))
    ack99=$(awk -v a="$ack99" -v b="$(p99 "$f" ack_latency_ms)" 'BEGIN { print (b > a ? b : a) }')
    bc99=$(awk -v a="$bc99" -v b="$(p99 "$f" broadcast_latency_ms)" 'BEGIN { print (b > a ? b : a) }')
done
# Group-commit latency per tick on the survivors (seconds to ms).
commit50=0; commit99=0
for i in 1 2; do
    m=$(curl -s "http://127.0.0.1:$((port + 1 + i))/metrics" || true)
    q() { echo "$m" | grep -E "^strata_flush_seconds\{quantile=\"$1\"\}" | awk '{ printf "%.2f", $2 * 1000 }'; }
    c50=$(q 0.5); c99=$(q 0.99)
    commit50=$(awk -v a="$commit50" -v b="${c50:-0}" 'BEGIN { print (b > a ? b : a) }')
    commit99=$(awk -v a="$commit99" -v b="${c99:-0}" 'BEGIN { print (b > a ? b : a) }')
done
for i in 0 1 2; do
    report=$("$target/strata-admin" verify-acks --data-dir "$dir/node-$i" "$dir/acks-$i.jsonl" | tail -1)
    lost=$(( lost + $(echo "$report" | grep -oE '"failure_count":[0-9]+' | cut -d: -f2) ))
done
checked=ok
"$target/strata-admin" check --data-dir "$dir/node-1" > "$dir/check.out" 2>&1 || checked=failed
echo "check: $checked ($(tail -1 "$dir/check.out"))" >&2
echo "{\"nodes\":3,\"edits_accepted\":$edits,\"acked_lost\":$lost,\"replica_mismatches\":$mismatches,\"border_crossings\":$crossings,\"takeover_ms\":$takeover_ms,\"handoffs\":$handoffs,\"ack_p99_ms\":$ack99,\"broadcast_p99_ms\":$bc99,\"commit_p50_ms\":$commit50,\"commit_p99_ms\":$commit99}"
[ "$lost" = 0 ] && [ "$mismatches" = 0 ] && [ "$checked" = ok ]
