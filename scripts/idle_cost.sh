#!/usr/bin/env bash
# What an idle server costs: a release strata-server with no clients, its
# CPU share and context switches per second per thread name over SECONDS
# (default 10), read from /proc.
# Usage: scripts/idle_cost.sh [SECONDS]      scripts/idle_cost.sh --help
# STRATA_SERVER_BIN runs another server binary (A/B runs); otherwise
# ${CARGO_TARGET_DIR:-target}/release/strata-server, built first.
set -euo pipefail
if [ "${1:-}" = -h ] || [ "${1:-}" = --help ]; then
    sed -n '2,/^set -euo/{/^set -euo/d; s/^# \{0,1\}//; p}' "$0"
    exit 0
fi
cd "$(dirname "$0")/.."
seconds=${1:-10}
bin=${STRATA_SERVER_BIN:-}
if [ -z "$bin" ]; then
    cargo build --release --locked -q -p strata-server --bins
    bin=${CARGO_TARGET_DIR:-target}/release/strata-server
fi
dir=$(mktemp -d)
pid=
trap 'kill ${pid:-} 2>/dev/null || true; rm -rf "$dir"' EXIT
printf '[server]\nlisten = "127.0.0.1:0"\n' > "$dir/strata.toml"
"$bin" --config "$dir/strata.toml" --data-dir "$dir/data" > "$dir/out" 2> "$dir/log" &
pid=$!
for _ in $(seq 100); do grep -q listening "$dir/out" 2>/dev/null && break; sleep 0.1; done
sleep 2   # past start-up
# utime + stime in clock ticks (fields 14 and 15, counted after the name).
ticks() { local s; read -r s < "/proc/$pid/stat"; s=${s##*) }; set -- $s; echo $(( ${12} + ${13} )); }
switches() {
    for t in /proc/"$pid"/task/*; do
        awk -v n="$(cat "$t/comm")" '/^(non)?voluntary_ctxt_switches/ { s += $2 } END { print n, s }' "$t/status"
    done | awk '{ s[$1] += $2 } END { for (k in s) print k, s[k] }' | sort
}
t0=$(ticks); switches > "$dir/a"; sleep "$seconds"; t1=$(ticks); switches > "$dir/b"
hz=$(getconf CLK_TCK)
awk -v c=$(( t1 - t0 )) -v hz="$hz" -v s="$seconds" 'BEGIN { printf "idle server: %.1f %% of a core over %d s\n", 100 * c / hz / s, s }'
join "$dir/a" "$dir/b" | awk -v s="$seconds" '$3 > $2 { printf "  %-18s %8.0f switches/s\n", $1, ($3 - $2) / s }'
