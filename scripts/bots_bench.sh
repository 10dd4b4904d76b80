#!/usr/bin/env bash
# Load test: a release strata-server process and strata-bots on this machine.
# Usage: scripts/bots_bench.sh BOTS [DURATION] [EXTRA strata-bots ARGS...]
# Prints the bots' JSON summary, then one JSON line with the server's CPU
# seconds (user+system, during the run), CPU share of one core, and peak RSS,
# and the bots process's CPU seconds. BENCH_SERVER_TOML appends lines to the
# server's config (e.g. $'[engine]\ntick_ms = 20'). STRATA_SERVER_BIN runs
# another server binary (A/B runs). BENCH_PER_ADDRESS sets the server's
# handshakes per address (default: room for every bot, which all connect
# from 127.0.0.1); BENCH_OLD_SERVER=1 leaves the admission settings out for
# a server older than them. BENCH_METRICS_PORT turns on the metrics
# endpoint and prints one more JSON line: the group-commit latency
# (strata_flush_seconds) and its fsync part, p50/p99/max in ms.
set -euo pipefail
cd "$(dirname "$0")/.."
bots=${1:?bots}; duration=${2:-30s}; shift $(( $# >= 2 ? 2 : 1 ))
target=${CARGO_TARGET_DIR:-target}
cargo build --release --locked -q -p strata-server -p strata-client-sim --bins
dir=$(mktemp -d)
trap 'kill $pid 2>/dev/null || true; [ -n "${BENCH_LOG:-}" ] && cp "$dir/log" "$BENCH_LOG"; rm -rf "$dir"' EXIT
cat > "$dir/strata.toml" <<TOML
[server]
listen = "127.0.0.1:0"
max_connections = $((bots + 64))
${BENCH_SERVER_TOML:-}
TOML
# Servers before the admission limits (issue #14) refuse these keys.
if [ -z "${BENCH_OLD_SERVER:-}" ]; then
    sed -i "/^max_connections/a max_handshakes = $((bots + 64))\nmax_handshakes_per_address = ${BENCH_PER_ADDRESS:-$((bots + 64))}" "$dir/strata.toml"
fi
if [ -n "${BENCH_METRICS_PORT:-}" ]; then
    printf '[metrics]\nlisten = "127.0.0.1:%s"\n' "$BENCH_METRICS_PORT" >> "$dir/strata.toml"
fi
"${STRATA_SERVER_BIN:-$target/release/strata-server}" --config "$dir/strata.toml" --data-dir "$dir/data" \
    > "$dir/out" 2> "$dir/log" &
pid=$!
for _ in $(seq 100); do grep -q listening "$dir/out" 2>/dev/null && break; sleep 0.1; done
addr=$(grep -oE '127\.0\.0\.1:[0-9]+' "$dir/out" | head -1)
ticks() { awk '{print $14 + $15}' "/proc/$pid/stat"; }
hz=$(getconf CLK_TCK)
t0=$(ticks); s0=$(date +%s.%N)
/usr/bin/time -f "%U %S" -o "$dir/bots_time" \
    "$target/release/strata-bots" --server "$addr" --data-dir "$dir/data" --bots "$bots" \
    --duration "$duration" --json "$@"
t1=$(ticks); s1=$(date +%s.%N)
rss=$(awk '/VmHWM/ {print $2}' "/proc/$pid/status")
bots_cpu=$(awk '{print $1 + $2}' "$dir/bots_time")
awk -v t0="$t0" -v t1="$t1" -v hz="$hz" -v s0="$s0" -v s1="$s1" -v rss="$rss" -v b="$bots_cpu" 'BEGIN {
    cpu = (t1 - t0) / hz; wall = s1 - s0;
    printf "{\"server_cpu_seconds\":%.2f,\"bots_cpu_seconds\":%.2f,\"wall_seconds\":%.2f,\"server_cpu_share\":%.2f,\"server_peak_rss_mib\":%.1f}\n",
        cpu, b, wall, cpu / wall, rss / 1024 }'
if [ -n "${BENCH_METRICS_PORT:-}" ]; then
    curl -s "http://127.0.0.1:$BENCH_METRICS_PORT/metrics" | awk '
        /^strata_(flush|fsync)_seconds\{quantile="(0.5|0.99|1)"\}/ {
            split($1, a, "[{\"]"); q[a[1] "_" a[3]] = $2 * 1000 }
        END { printf "{\"commit_ms\":{\"p50\":%.2f,\"p99\":%.2f,\"max\":%.2f},\"fsync_ms\":{\"p50\":%.2f,\"p99\":%.2f,\"max\":%.2f}}\n",
            q["strata_flush_seconds_0.5"], q["strata_flush_seconds_0.99"], q["strata_flush_seconds_1"],
            q["strata_fsync_seconds_0.5"], q["strata_fsync_seconds_0.99"], q["strata_fsync_seconds_1"] }'
fi
