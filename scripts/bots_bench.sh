#!/usr/bin/env bash
# Load test: a release strata-server process and strata-bots on this machine.
# Usage: scripts/bots_bench.sh BOTS [DURATION] [EXTRA strata-bots ARGS...]
#        scripts/bots_bench.sh --help
# Prints the bots' JSON summary, then one JSON line with the server's CPU
# seconds (user+system, all threads, during the run), CPU share of one core,
# and peak RSS, and the bots process's CPU seconds. BENCH_SERVER_TOML appends
# lines to the server's config (e.g. $'[engine]\ntick_ms = 20'); it follows
# the [server] table's keys, so keys before any header of its own are
# [server]'s (e.g. $'net_threads = 1\n[engine]\ntick_ms = 20').
# STRATA_SERVER_BIN runs another server binary (A/B runs). BENCH_PER_ADDRESS
# sets the server's handshakes per address (default: room for every bot,
# which all connect from 127.0.0.1); BENCH_OLD_SERVER=1 leaves the admission
# settings out for a server older than them. BENCH_METRICS_PORT turns on the
# metrics endpoint and prints one more JSON line: the group-commit latency
# (strata_flush_seconds) and its fsync part, p50/p99/max in ms, and the
# server's own strata_edits_accepted_total (hostile players' edits included),
# and "edit_ms": an edit's wait in the engine's queue (inbox: from its
# session decoding it to the engine taking it) and in the engine (from
# then to its ack), p50/p99/max in ms;
# BENCH_METRICS_DUMP=FILE also keeps the whole scrape, taken as the bots end.
# The same line has the tick: tick_ms mean (strata_tick_seconds sum over
# count, whole run), p50 and p99 (the registry's rolling window, the run's
# last minute) and the count of ticks; and "udp": the UDP datagrams the
# server sent and received, its UDP bytes sent, QUIC's lost packets, and
# datagrams (both ways) per edit it accepted; and "meshes": collision
# meshes built by kind (changed, rewarm, on_demand, premesh), what became of
# the rewarms (used, wasted) and meshes per edit; "store_bytes": encoded
# bytes handed to the store (strata_store_bytes_total: commit, checkpoint)
# and per edit; and "caches": lookups of
# the generated-chunk caches (premesh and patch bases: hits, generated) and
# of the snapshot-frame cache (hits, misses, frames evicted); "batches":
# sessions' batches of a tick's updates, written into the stream at once
# by a fan-out worker, begun there (the rest left to the writer), or
# queued to the writer task; and "requests_throttled": requests that waited for their session's
# [validation.request_rate] tokens (0 for the bots). BENCH_CONSOLE_PORT turns on
# the web console; BENCH_WATCHERS=N then connects N watching consoles once
# the server is up, each like a browser tab: the first screen of map tiles
# (3 x 3 around the bots), then the live event stream to the end.
# A line has the server's CPU seconds by thread name over the bots'
# run ("thread_cpu_seconds": strata-engine, tokio-rt-worker, strata-worker,
# ...), and one what it wrote over that run, from /proc/PID/io ("disk":
# wchar, the bytes its write calls passed, store and log; write_bytes, the
# bytes the page cache sent to the disk for it; write_calls; both per
# accepted edit), and one its threads' context switches over that run
# ("context_switches": voluntary, involuntary, both per accepted edit).
# BENCH_LOG=FILE keeps the server's log. Binaries come from
# ${CARGO_TARGET_DIR:-target}/release, built first, or from BENCH_BIN_DIR
# as they are (strata-server, strata-admin, strata-bots; no cargo needed:
# a machine the binaries were copied to).
#
# BENCH_SERVER_CPUS and BENCH_BOT_CPUS pin the server and the bots to CPU
# lists (taskset -c syntax: 0,1 or 2-7); unset, both run anywhere.
#
# The server line also has, per run:
#   edits_accepted          the bots' accepted edits (EditAccepted acks the
#                           honest bots received; the bots' JSON)
#   server_cpu_ms_per_edit  server CPU ms (whole run: ramp-up, editing,
#                           end-of-run check) per accepted edit
#   server_cpu_share        server CPU s / wall s: cores in use on average
#   deltas                  deltas the bots' replicas applied (the bots' JSON)
#   deltas_per_second       deltas / the editing time (--duration)
#   edit_*                  the same server figures over the editing window
#                           only (from ramp_s to ramp_s + duration_s of the
#                           bots' JSON; server CPU sampled every 0.1 s):
#                           edit_window_seconds, edit_server_cpu_seconds,
#                           edit_server_cores, edit_server_cpu_ms_per_edit
#   server_cpus, bots_cpus  the pins (null: none)
# and one human-readable line of them goes to stderr. BENCH_CSV=FILE appends
# the same figures as a CSV row (header first when FILE is new or empty),
# with the bots' ack p50 and p99 and broadcast p99 in ms, and their
# replica, mesh, op and order mismatches summed.
set -euo pipefail
if [ "${1:-}" = -h ] || [ "${1:-}" = --help ]; then
    sed -n '2,/^set -euo/{/^set -euo/d; s/^# \{0,1\}//; p}' "$0"
    exit 0
fi
cd "$(dirname "$0")/.."
bots=${1:?bots}; duration=${2:-30s}; shift $(( $# >= 2 ? 2 : 1 ))
target=${CARGO_TARGET_DIR:-target}
server_pin=(); bots_pin=()
if [ -n "${BENCH_SERVER_CPUS:-}" ]; then
    taskset -c "$BENCH_SERVER_CPUS" true   # fails here on a bad list
    server_pin=(taskset -c "$BENCH_SERVER_CPUS")
fi
if [ -n "${BENCH_BOT_CPUS:-}" ]; then
    taskset -c "$BENCH_BOT_CPUS" true
    bots_pin=(taskset -c "$BENCH_BOT_CPUS")
fi
if [ -n "${BENCH_BIN_DIR:-}" ]; then
    bin=$BENCH_BIN_DIR
else
    cargo build --release --locked -q -p strata-server -p strata-client-sim --bins
    bin=$target/release
fi
for b in strata-server strata-admin strata-bots; do
    [ -x "$bin/$b" ] || { echo "bots_bench: no $bin/$b" >&2; exit 1; }
done
dir=$(mktemp -d)
pid=; sampler=; watchers=()
# The server is waited for (10 s, then SIGKILL): a run right after this one
# must find its ports free (scripts/scaling_table.sh).
stop_server() {
    [ -n "${pid:-}" ] || return 0
    kill "$pid" 2>/dev/null || return 0
    for _ in $(seq 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -9 "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
}
trap 'kill ${watchers[*]:-} ${sampler:-} 2>/dev/null || true; stop_server; [ -n "${BENCH_LOG:-}" ] && cp "$dir/log" "$BENCH_LOG"; rm -rf "$dir"' EXIT
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
if [ -n "${BENCH_CONSOLE_PORT:-}" ]; then
    printf '[console]\nlisten = "127.0.0.1:%s"\n' "$BENCH_CONSOLE_PORT" >> "$dir/strata.toml"
fi
# taskset execs the server: $! is the server's pid either way.
"${server_pin[@]}" "${STRATA_SERVER_BIN:-$bin/strata-server}" \
    --config "$dir/strata.toml" --data-dir "$dir/data" > "$dir/out" 2> "$dir/log" &
pid=$!
for _ in $(seq 100); do grep -q listening "$dir/out" 2>/dev/null && break; sleep 0.1; done
addr=$(grep -oE '127\.0\.0\.1:[0-9]+' "$dir/out" | head -1)
if [ "${BENCH_WATCHERS:-0}" -gt 0 ]; then
    token=$("$bin/strata-admin" token issue --data-dir "$dir/data" \
        --player bench --role admin --ttl 1h | tail -1)
    console="http://127.0.0.1:${BENCH_CONSOLE_PORT:?BENCH_WATCHERS needs BENCH_CONSOLE_PORT}"
    for _ in $(seq "$BENCH_WATCHERS"); do
        ( for tz in 3 4 5; do for tx in 3 4 5; do
              curl -s -o /dev/null -H "Authorization: Bearer $token" "$console/api/tile?tx=$tx&tz=$tz"
          done; done
          exec curl -s -N -o /dev/null -H "Authorization: Bearer $token" "$console/api/events" ) &
        watchers+=($!)
    done
fi
# utime + stime (fields 14 and 15) in clock ticks; the fields are counted
# after the command name, which may hold spaces.
ticks() { local s; read -r s < "/proc/$pid/stat"; s=${s##*) }; set -- $s; echo $(( ${12} + ${13} )); }
hz=$(getconf CLK_TCK)
# "epoch-seconds ticks" every 0.1 s, for the editing window.
sample() { local t; while t=$(ticks 2>/dev/null); do echo "$EPOCHREALTIME $t"; sleep 0.1; done; }
sample > "$dir/samples" 2>/dev/null &
sampler=$!
# "name ticks" per server thread (names without their trailing numbers).
threads() {
    local t c s
    for t in /proc/"$pid"/task/*; do
        read -r c < "$t/comm" 2>/dev/null && read -r s < "$t/stat" 2>/dev/null || continue
        s=${s##*) }; set -- $s
        c=${c%%[0-9]*}; echo "${c%-} $(( ${12} + ${13} ))"
    done
}
# "voluntary involuntary" context switches summed over the server's threads.
switches() {
    awk '/^voluntary_ctxt_switches/ { v += $2 } /^nonvoluntary_ctxt_switches/ { n += $2 }
        END { print v + 0, n + 0 }' /proc/"$pid"/task/*/status 2>/dev/null
}
threads > "$dir/threads0"
switches > "$dir/switches0"
cp "/proc/$pid/io" "$dir/io0"
t0=$(ticks); s0=$(date +%s.%N)
/usr/bin/time -f "%U %S" -o "$dir/bots_time" \
    "${bots_pin[@]}" "$bin/strata-bots" --server "$addr" --data-dir "$dir/data" \
    --bots "$bots" --duration "$duration" --json "$@" | tee "$dir/bots.json"
t1=$(ticks); s1=$(date +%s.%N)
threads > "$dir/threads1"
switches > "$dir/switches1"
cp "/proc/$pid/io" "$dir/io1"
kill "$sampler" 2>/dev/null || true; wait "$sampler" 2>/dev/null || true; sampler=
rss=$(awk '/VmHWM/ {print $2}' "/proc/$pid/status")
bots_cpu=$(awk '{print $1 + $2}' "$dir/bots_time")
# Top-level numbers of the bots' JSON (serde writes them before any nested
# object that could repeat a name).
field() { grep -oE "\"$1\":[-0-9.eE+]+" "$dir/bots.json" | head -1 | cut -d: -f2; }
edits=$(field edits_accepted); deltas=$(field deltas)
# A quantile of one of the bots' latency objects ("ack_latency_ms", ...).
quantile() { grep -oE "\"$1\":\\{[^}]*\\}" "$dir/bots.json" | head -1 | grep -oE "\"$2\":[0-9.]+" | cut -d: -f2; }
ack_p50=$(quantile ack_latency_ms p50); ack_p99=$(quantile ack_latency_ms p99)
bc_p99=$(quantile broadcast_latency_ms p99)
mismatches=0
for f in replica_mismatches mesh_mismatches op_mismatches order_violations; do
    mismatches=$(( mismatches + $(field "$f" || true) + 0 ))
done
duration_s=$(field duration_s); ramp_s=$(field ramp_s)
awk -v t0="$t0" -v t1="$t1" -v hz="$hz" -v s0="$s0" -v s1="$s1" -v rss="$rss" -v b="$bots_cpu" \
    -v edits="${edits:-0}" -v deltas="${deltas:-0}" -v dur="${duration_s:-0}" -v ramp="${ramp_s:-0}" \
    -v bots="$bots" -v scpus="${BENCH_SERVER_CPUS:-}" -v bcpus="${BENCH_BOT_CPUS:-}" \
    -v csv="${BENCH_CSV:-}" -v samples="$dir/samples" \
    -v ack50="${ack_p50:-}" -v ack99="${ack_p99:-}" -v bc99="${bc_p99:-}" -v mism="$mismatches" '
    function at(t,   i) {  # server ticks at epoch t, interpolated
        if (n == 0) return 0
        if (t <= ts[1]) return tk[1]
        for (i = 2; i <= n; i++)
            if (t <= ts[i]) return tk[i-1] + (tk[i] - tk[i-1]) * (t - ts[i-1]) / (ts[i] - ts[i-1])
        return tk[n]
    }
    function orn(x) { return x == "" ? "null" : x }   # JSON: empty is null
    function ord(x) { return x == "" ? "-" : x }      # text: empty is -
    function str(x) { return x == "" ? "null" : "\"" x "\"" }
    BEGIN {
        while ((getline line < samples) > 0) { split(line, a, " "); ts[++n] = a[1]; tk[n] = a[2] }
        cpu = (t1 - t0) / hz; wall = s1 - s0
        per_edit = edits > 0 ? sprintf("%.3f", 1000 * cpu / edits) : ""
        dps = dur > 0 ? sprintf("%.1f", deltas / dur) : ""
        # The editing window, in epoch seconds (the bots start at about s0).
        w0 = s0 + ramp; w1 = w0 + dur
        if (n >= 2 && dur > 0 && w1 <= ts[n] + 0.2) {
            ecpu = sprintf("%.2f", (at(w1) - at(w0)) / hz)
            ecores = sprintf("%.2f", ecpu / dur)
            eper = edits > 0 ? sprintf("%.3f", 1000 * ecpu / edits) : ""
            ewin = sprintf("%.2f", dur)
        }
        printf "{\"server_cpu_seconds\":%.2f,\"bots_cpu_seconds\":%.2f,\"wall_seconds\":%.2f,\"server_cpu_share\":%.2f,\"server_peak_rss_mib\":%.1f", \
            cpu, b, wall, cpu / wall, rss / 1024
        printf ",\"edits_accepted\":%d,\"server_cpu_ms_per_edit\":%s,\"deltas\":%d,\"deltas_per_second\":%s", \
            edits, orn(per_edit), deltas, orn(dps)
        printf ",\"edit_window_seconds\":%s,\"edit_server_cpu_seconds\":%s,\"edit_server_cores\":%s,\"edit_server_cpu_ms_per_edit\":%s", \
            orn(ewin), orn(ecpu), orn(ecores), orn(eper)
        printf ",\"server_cpus\":%s,\"bots_cpus\":%s}\n", str(scpus), str(bcpus)
        printf "bots_bench: %d bots, %s s editing: %d edits accepted, %d deltas delivered (%s/s); server %.2f CPU s in %.2f s = %.2f cores, %s ms/edit", \
            bots, dur, edits, deltas, ord(dps), cpu, wall, cpu / wall, ord(per_edit) > "/dev/stderr"
        if (ecpu != "")
            printf "; editing window %.2f CPU s = %s cores, %s ms/edit", ecpu, ecores, ord(eper) > "/dev/stderr"
        printf "; bots %.2f CPU s; pins server %s, bots %s\n", b, ord(scpus), ord(bcpus) > "/dev/stderr"
        if (csv != "") {
            if ((getline line < csv) <= 0)
                print "bots,duration_s,server_cpus,bots_cpus,edits_accepted,deltas,deltas_per_second,server_cpu_seconds,wall_seconds,server_cpu_share,server_cpu_ms_per_edit,edit_server_cpu_seconds,edit_server_cores,edit_server_cpu_ms_per_edit,bots_cpu_seconds,server_peak_rss_mib,ack_p50_ms,ack_p99_ms,broadcast_p99_ms,mismatches" >> csv
            close(csv)
            printf "%d,%s,\"%s\",\"%s\",%d,%d,%s,%.2f,%.2f,%.2f,%s,%s,%s,%s,%.2f,%.1f,%s,%s,%s,%d\n", bots, dur, scpus, bcpus, edits, deltas, dps, \
                cpu, wall, cpu / wall, per_edit, ecpu, ecores, eper, b, rss / 1024, ack50, ack99, bc99, mism >> csv
        }
    }'
# Server CPU seconds by thread name over the bots' run (threads that ended
# during it are missing).
awk -v hz="$hz" 'FNR == NR { a[$1] += $2; next } { b[$1] += $2 }
    END { printf "{\"thread_cpu_seconds\":{"; sep = ""
          for (k in b) { printf "%s\"%s\":%.2f", sep, k, (b[k] - a[k]) / hz; sep = "," }
          print "}}" }' "$dir/threads0" "$dir/threads1"
# The server's threads' context switches over the bots' run (threads that
# ended during it are missing): voluntary (it slept: waits, parks) and
# involuntary (preempted), and both per accepted edit.
read -r v0 n0 < "$dir/switches0"
read -r v1 n1 < "$dir/switches1"
awk -v v=$((v1 - v0)) -v n=$((n1 - n0)) -v edits="${edits:-0}" 'BEGIN {
    printf "{\"context_switches\":{\"voluntary\":%d,\"involuntary\":%d,\"per_edit\":%.1f}}\n",
        v, n, (edits > 0 ? (v + n) / edits : 0) }'
# What the server wrote over the bots' run (/proc/PID/io): bytes passed to
# write calls (the store's files and the log), and bytes the page cache
# sent to the disk for it.
awk -v edits="${edits:-0}" 'FNR == NR { a[$1] = $2; next } { b[$1] = $2 }
    END { w = b["wchar:"] - a["wchar:"]; d = b["write_bytes:"] - a["write_bytes:"]
          printf "{\"disk\":{\"wchar\":%d,\"write_bytes\":%d,\"write_calls\":%d,\"wchar_per_edit\":%.0f,\"write_bytes_per_edit\":%.0f}}\n",
              w, d, b["syscw:"] - a["syscw:"], (edits > 0 ? w / edits : 0), (edits > 0 ? d / edits : 0) }' \
    "$dir/io0" "$dir/io1"
if [ -n "${BENCH_METRICS_PORT:-}" ]; then
    [ -z "${BENCH_METRICS_DUMP:-}" ] ||
        curl -s -o "$BENCH_METRICS_DUMP" "http://127.0.0.1:$BENCH_METRICS_PORT/metrics"
    curl -s "http://127.0.0.1:$BENCH_METRICS_PORT/metrics" | awk '
        /^strata_(flush|fsync|edit_inbox|edit_latency)_seconds\{quantile="(0.5|0.99|1)"\}/ {
            split($1, a, "[{\"]"); q[a[1] "_" a[3]] = $2 * 1000 }
        /^strata_edits_accepted_total[ {]/ { accepted += $NF }
        /^strata_tick_seconds\{quantile="(0.5|0.99)"\}/ {
            split($1, a, "[{\"]"); q[a[1] "_" a[3]] = $2 * 1000 }
        /^strata_tick_seconds_sum / { tsum = $2 }
        /^strata_tick_seconds_count / { tcount = $2 }
        /^strata_udp_datagrams_total\{direction="sent"\}/ { dsent = $NF }
        /^strata_udp_datagrams_total\{direction="received"\}/ { drecv = $NF }
        /^strata_udp_bytes_total\{direction="sent"\}/ { bsent = $NF }
        /^strata_quic_lost_packets_total / { lost = $NF }
        /^strata_collision_meshes_total\{/ { split($1, a, "\""); meshes[a[2]] = $NF }
        /^strata_collision_rewarms_total\{/ { split($1, a, "\""); rewarms[a[2]] = $NF }
        /^strata_premesh_meshes_total / { premesh = $NF }
        /^strata_generated_chunks_total\{/ { split($1, a, "\""); gen[a[2] "_" a[4]] = $NF }
        /^strata_snapshot_cache_total\{/ { split($1, a, "\""); snap[a[2]] = $NF }
        /^strata_requests_throttled_total / { throttled = $NF }
        /^strata_fanout_batches_total\{/ { split($1, a, "\""); batches[a[2]] = $NF }
        /^strata_store_bytes_total\{/ { split($1, a, "\""); store[a[2]] = $NF }
        END { printf "{\"commit_ms\":{\"p50\":%.2f,\"p99\":%.2f,\"max\":%.2f},\"fsync_ms\":{\"p50\":%.2f,\"p99\":%.2f,\"max\":%.2f},\"server_edits_accepted\":%d",
            q["strata_flush_seconds_0.5"], q["strata_flush_seconds_0.99"], q["strata_flush_seconds_1"],
            q["strata_fsync_seconds_0.5"], q["strata_fsync_seconds_0.99"], q["strata_fsync_seconds_1"], accepted
              printf ",\"edit_ms\":{\"inbox_p50\":%.2f,\"inbox_p99\":%.2f,\"inbox_max\":%.2f,\"engine_p50\":%.2f,\"engine_p99\":%.2f,\"engine_max\":%.2f}",
            q["strata_edit_inbox_seconds_0.5"], q["strata_edit_inbox_seconds_0.99"], q["strata_edit_inbox_seconds_1"],
            q["strata_edit_latency_seconds_0.5"], q["strata_edit_latency_seconds_0.99"], q["strata_edit_latency_seconds_1"]
              printf ",\"tick_ms\":{\"mean\":%.3f,\"p50\":%.3f,\"p99\":%.3f,\"count\":%d}",
            (tcount > 0 ? 1000 * tsum / tcount : 0), q["strata_tick_seconds_0.5"], q["strata_tick_seconds_0.99"], tcount
              printf ",\"udp\":{\"datagrams_sent\":%d,\"datagrams_received\":%d,\"bytes_sent\":%d,\"lost_packets\":%d,\"datagrams_per_edit\":%.1f}",
            dsent, drecv, bsent, lost, (accepted > 0 ? (dsent + drecv) / accepted : 0)
              printf ",\"meshes\":{\"changed\":%d,\"rewarm\":%d,\"on_demand\":%d,\"premesh\":%d,\"rewarm_used\":%d,\"rewarm_wasted\":%d,\"per_edit\":%.2f}",
            meshes["changed"], meshes["rewarm"], meshes["on_demand"], premesh, rewarms["used"], rewarms["wasted"],
            (accepted > 0 ? (meshes["changed"] + meshes["rewarm"] + meshes["on_demand"] + premesh) / accepted : 0)
              printf ",\"store_bytes\":{\"commit\":%d,\"checkpoint\":%d,\"per_edit\":%.0f}",
            store["commit"], store["checkpoint"], (accepted > 0 ? (store["commit"] + store["checkpoint"]) / accepted : 0)
              printf ",\"caches\":{\"premesh_hit\":%d,\"premesh_generated\":%d,\"patch_base_hit\":%d,\"patch_base_generated\":%d,\"snapshot_hit\":%d,\"snapshot_miss\":%d,\"snapshot_evicted\":%d,\"snapshot_evicted_requested\":%d},\"batches\":{\"written\":%d,\"begun\":%d,\"queued\":%d},\"requests_throttled\":%d}\n",
            gen["premesh_hit"], gen["premesh_generated"], gen["patch_base_hit"], gen["patch_base_generated"],
            snap["hit"], snap["miss"], snap["evicted"], snap["evicted_requested"], batches["written"], batches["begun"], batches["queued"], throttled }'
fi
