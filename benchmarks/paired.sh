#!/usr/bin/env bash
# Paired whole-process timing of two commands: A B A B ... (N pairs, after one unpaired warm-up run of each),
# so that a comparison holds while the machine's speed drifts. Prints each run's wall seconds and, for
# arteq-fit commands, the figure the command prints per fitted scan; then the medians and the median of the
# pairwise wall ratios A/B. Quote medians and ratios, not single runs.
#   bash benchmarks/paired.sh N 'COMMAND A' 'COMMAND B'
# e.g. this code against the commit before (a worktree of it first on PYTHONPATH), the user suite's 14 exported
# scans (experiments/fitting/user_scans.py --export scans --export-only), batch 4, two threads:
#   bash benchmarks/paired.sh 3 \
#     'python -m arteq.fit scans --out A --threads 2 --no-anny --no-preview --overwrite' \
#     'env PYTHONPATH=<worktree>/src python -m arteq.fit scans --out B --threads 2 --no-anny --no-preview --overwrite'
set -euo pipefail
[ $# -eq 3 ] || { echo "usage: $0 N 'COMMAND A' 'COMMAND B'" >&2; exit 2; }
n=$1
log=$(mktemp -d)
run() {  # run LABEL COMMAND: prints "LABEL wall_s per_scan_s"
  local t0 t1 per
  t0=$(date +%s.%N)
  bash -c "$2" > "$log/out" 2>&1 || { echo "$1: command failed (output: $log/out)" >&2; exit 1; }
  t1=$(date +%s.%N)
  per=$({ grep -o '[0-9.]* s per fitted scan' "$log/out" || true; } | tail -n 1 | cut -d' ' -f1)
  echo "$1 $(echo "$t1 - $t0" | bc -l) ${per:--}"
}
run warmup-A "$2" > /dev/null
run warmup-B "$3" > /dev/null
for i in $(seq "$n"); do
  run A "$2"
  run B "$3"
done | tee "$log/runs"
python3 - "$log/runs" <<'EOF'
import statistics as st
import sys

rows = [line.split() for line in open(sys.argv[1])]
a = [r for r in rows if r[0] == "A"]
b = [r for r in rows if r[0] == "B"]
for name, rs in (("A", a), ("B", b)):
    wall = [float(r[1]) for r in rs]
    per = [float(r[2]) for r in rs if r[2] != "-"]
    line = f"{name}: wall {st.median(wall):.2f} s median ({min(wall):.2f}-{max(wall):.2f})"
    if per:
        line += f", per fitted scan {st.median(per):.2f} s ({min(per):.2f}-{max(per):.2f})"
    print(line)
ratios = [float(x[1]) / float(y[1]) for x, y in zip(a, b)]
print(f"wall ratio A/B {st.median(ratios):.2f} median ({min(ratios):.2f}-{max(ratios):.2f})")
EOF
