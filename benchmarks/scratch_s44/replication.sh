#!/bin/bash
# Session 44: the analysis written down in results/quick_centred/PREREG_s44.md, on the fresh seeds 24..LAST.
#   bash benchmarks/scratch_s44/replication.sh LAST [OUT]
# Primary: active_admission − random_plan in area on seeds 24..LAST alone. Secondary (descriptive): pooled 0..LAST,
# rounds 1-3 on the fresh seeds, by round. OUT (optional): a report of the fresh seeds alone (active.report).
set -euo pipefail
last=$1
W="python benchmarks/scratch_s43/window_diff.py results/quick_centred/csv active_admission random_plan"
export PYTHONPATH=.
echo "== primary: fresh seeds only"; $W --seeds 24 "$last" --by-round
echo "== secondary: rounds 1-3, fresh seeds"; $W --rounds 1 3 --seeds 24 "$last"
echo "== secondary: pooled 0-$last (a second look: not a test)"; $W --seeds 0 "$last" --by-round
echo "== pooled rounds 1-3"; $W --rounds 1 3 --seeds 0 "$last"
if [ $# -ge 2 ]; then
  dirs=$(for s in $(seq 24 "$last"); do echo results/quick_centred/csv/seed$s; done)
  python -m active.report $dirs --out "$2" --reference random_plan --ceiling benchmarks/results/ladder_s42_default.json
fi
