#!/usr/bin/env bash
# Interleaved A/B of two builds of the pipeline bench.
# Usage: scripts/pipeline_ab.sh A_BENCH B_BENCH PAIRS [WORKERS]
#        scripts/pipeline_ab.sh --help
# A_BENCH and B_BENCH are pipeline bench binaries (`cargo bench -p
# strata-server --bench pipeline --no-run` prints the path; copy it aside
# before building the other side). Runs PAIRS pairs at WORKERS workers
# (default 2), A first in odd pairs and B first in even ones, so that the
# box's drift falls on both alike; prints each run's table row, then for
# each pair B/A of durable edits/s and of CPU ms per edit, and their
# medians. STRATA_BENCH_SECONDS (default 5) and STRATA_BENCH_EDITS_PER_TICK
# (default 1024) are passed on.
set -euo pipefail

if [[ ${1:-} == --help || ${1:-} == -h || $# -lt 3 ]]; then
    sed -n '2,/^set -euo/p' "$0" | sed '$d' | sed 's/^# \{0,1\}//'
    [[ ${1:-} == --help || ${1:-} == -h ]] && exit 0 || exit 2
fi
a=$1 b=$2 pairs=$3 workers=${4:-2}
for f in "$a" "$b"; do
    [[ -x $f ]] || {
        echo "pipeline_ab: $f is not an executable" >&2
        exit 2
    }
done
export STRATA_BENCH_SECONDS=${STRATA_BENCH_SECONDS:-5}
export STRATA_BENCH_EDITS_PER_TICK=${STRATA_BENCH_EDITS_PER_TICK:-1024}

row() { # NAME BIN: the row of the table, without its leading "|"
    local r
    r=$("$2" "$workers" 2>&1 | grep '^| [0-9]' | head -1) || true
    echo "$1 ${r#| }"
}

results=()
for i in $(seq 1 "$pairs"); do
    if ((i % 2)); then order=(A B); else order=(B A); fi
    for side in "${order[@]}"; do
        bin=$a
        [[ $side == B ]] && bin=$b
        line=$(row "$side$i" "$bin")
        echo "$line"
        results+=("$line")
    done
done

printf '%s\n' "${results[@]}" | awk -F'|' '
    # Fields after the name: workers, durable edits/s, deltas/s, deltas/edit, CPU ms/edit.
    {
        split($1, head, " "); name = head[1]; side = substr(name, 1, 1); pair = substr(name, 2)
        eps[side, pair] = $2 + 0; cpu[side, pair] = $5 + 0; if (pair > n) n = pair
    }
    function median(v, k,    i, j, t) {
        for (i = 1; i <= k; i++) for (j = i + 1; j <= k; j++) if (v[j] < v[i]) { t = v[i]; v[i] = v[j]; v[j] = t }
        return k % 2 ? v[(k + 1) / 2] : (v[k / 2] + v[k / 2 + 1]) / 2
    }
    END {
        k = 0
        for (p = 1; p <= n; p++) {
            if (!eps["A", p] || !eps["B", p] || !cpu["A", p]) continue
            k++; re[k] = eps["B", p] / eps["A", p]; rc[k] = cpu["B", p] / cpu["A", p]
            printf "pair %d: %d -> %d durable edits/s (B/A %.3f), CPU ms/edit B/A %.3f\n", p, eps["A", p], eps["B", p], re[k], rc[k]
        }
        if (k) printf "B/A over %d pairs: durable edits/s median %.3f, CPU ms per edit median %.3f\n", k, median(re, k), median(rc, k)
    }'
