#!/usr/bin/env bash
# Interleaved A/B of two server builds under scripts/bots_bench.sh.
# Usage: scripts/bots_ab.sh A_BIN_DIR B_BIN_DIR PAIRS BOTS [DURATION] [strata-bots ARGS...]
#        scripts/bots_ab.sh --help
# Each directory holds strata-server, strata-admin and strata-bots (as
# BENCH_BIN_DIR of bots_bench.sh); when only the server changed, give both
# the same strata-bots (the bots share the box's cores with the server). Runs PAIRS pairs, A then B in odd pairs
# and B then A in even ones, so that the box's drift (20-40 % within an
# hour on shared machines) falls on both alike. Prints one line a run
# (server CPU ms per accepted edit over the editing window, ack p50/p99 of
# accepted edits and beside them what they do not time: edits rejected,
# unanswered, and edit slots skipped while an edit awaited its verdict;
# accepted edits, CPU seconds of the engine, worker and tokio threads, the
# server's context switches per edit, any mismatch), then B/A of the CPU
# per edit for each pair and their median: the figure to quote, with its
# pairs. A pair with a failed run (bots_bench.sh failed: a mismatch, a
# crash, no result) is marked INVALID and left out of the median, the
# final line says how many runs failed, and the script exits 1.
# The other bots_bench.sh settings
# (BENCH_SERVER_TOML, BENCH_SERVER_CPUS, BENCH_BOT_CPUS, ...) apply to both.
# BENCH_AB_KEEP=DIR keeps each run's output there (A1.log, B1.log, ...).
# Needs python3 to read the JSON lines.
set -euo pipefail

if [[ ${1:-} == --help || ${1:-} == -h || $# -lt 4 ]]; then
    sed -n '2,/^set -euo/p' "$0" | sed '$d' | sed 's/^# \{0,1\}//'
    [[ ${1:-} == --help || ${1:-} == -h ]] && exit 0 || exit 2
fi
command -v python3 >/dev/null || {
    echo "bots_ab: needs python3" >&2
    exit 2
}
a=$1 b=$2 pairs=$3 bots=$4
shift 4
duration=${1:-20s}
[[ $# -gt 0 ]] && shift
extra=("$@")
for d in "$a" "$b"; do
    for bin in strata-server strata-admin strata-bots; do
        [[ -x $d/$bin ]] || {
            echo "bots_ab: $d/$bin is missing" >&2
            exit 2
        }
    done
done
here=$(cd "$(dirname "$0")" && pwd)
keep=${BENCH_AB_KEEP:-$(mktemp -d)}
mkdir -p "$keep"
# The runs that failed (NAME PAIR a line), this invocation's only.
failed="$keep/failed_runs"
: >"$failed"

run() { # NAME DIR PAIR
    local log="$keep/$1$3.log"
    if ! BENCH_BIN_DIR=$2 "$here/bots_bench.sh" "$bots" "$duration" --verify modified "${extra[@]}" >"$log" 2>&1; then
        echo "bots_ab: run $1$3 failed (see $log)" >&2
        echo "$1 $3" >>"$failed"
    fi
    python3 - "$log" "$1" "$3" <<'PY'
import json, sys
path, name, pair = sys.argv[1:4]
rows = [json.loads(l) for l in open(path) if l.startswith('{')]
if len(rows) < 2:
    print(f"{name}{pair}: no result"); sys.exit()
bots, cpu = rows[0], rows[1]
threads = next((r['thread_cpu_seconds'] for r in rows if 'thread_cpu_seconds' in r), {})
switches = next((r['context_switches'] for r in rows if 'context_switches' in r), {})
bad = {k: v for k, v in bots.items() if 'mismatch' in k and v}
ack = bots.get('ack_latency_ms', {})
rejected = sum(bots.get('edits_rejected', {}).values())
print(f"{name}{pair}: {cpu['edit_server_cpu_ms_per_edit']} ms/edit, ack p50/p99 "
      f"{ack.get('p50')}/{ack.get('p99')} ms (not timed: {rejected} rejected, "
      f"{bots.get('edits_unanswered')} unanswered, {bots.get('edit_slots_skipped')} slots skipped), "
      f"{bots.get('edits_accepted')} edits, CPU s engine "
      f"{threads.get('strata-engine')} workers {threads.get('strata-worker')} tokio "
      f"{threads.get('tokio-rt-worker')}, switches/edit {switches.get('per_edit')}, "
      f"mismatches {bad or 0}")
PY
}

for i in $(seq 1 "$pairs"); do
    if ((i % 2)); then
        run A "$a" "$i"
        run B "$b" "$i"
    else
        run B "$b" "$i"
        run A "$a" "$i"
    fi
done

status=0
python3 - "$keep" "$pairs" "$failed" <<'PY' || status=1
import json, statistics, sys
keep, pairs, failed_path = sys.argv[1], int(sys.argv[2]), sys.argv[3]
failed = {tuple(l.split()) for l in open(failed_path) if l.strip()}
def ms(name, i):
    try:
        rows = [json.loads(l) for l in open(f"{keep}/{name}{i}.log") if l.startswith('{')]
        return rows[1]['edit_server_cpu_ms_per_edit']
    except (OSError, IndexError, KeyError, ValueError):
        return None
ratios, invalid = [], []
for i in range(1, pairs + 1):
    a, b = ms('A', i), ms('B', i)
    bad = [n for n in ('A', 'B') if (n, str(i)) in failed or ms(n, i) is None]
    if bad or not a or not b:
        invalid.append(i)
        why = ', '.join(f"{n}{i} failed" for n in bad) or 'no CPU per edit'
        print(f"pair {i}: INVALID ({why}), left out of the median")
        continue
    ratios.append(b / a)
    print(f"pair {i}: {a} -> {b} ms/edit, B/A {b / a:.3f}")
median = (f"median {statistics.median(ratios):.3f} over {len(ratios)} pairs "
          f"(lower in {sum(r < 1 for r in ratios)})") if ratios else "no valid pair"
if invalid:
    print(f"B/A CPU per edit: INVALID: {len(failed)} failed runs, pairs {invalid} left out; "
          f"{median} of {pairs}")
    sys.exit(1)
print(f"B/A CPU per edit: {median}")
PY
echo "runs kept in $keep"
exit "$status"
