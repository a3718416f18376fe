#!/bin/bash
# Scratch (session 45): would the factored transfers pay in 2D? The default world's scene at B = 32
# (benchmarks.sim_solver --scene world), 2D direct (the default) against 2D factored (sim.mpm._FACTORED_TRANSFERS
# = (2, 3), read when the kernels compile), alternating, each against its in-process mpm88 reference.
#   bash benchmarks/scratch_s45/factored_2d.sh [OUTDIR]
OUT=${1:-/tmp/s45_factored_2d}
mkdir -p "$OUT"
for r in ${ROUNDS:-1 2}; do
  for dims in "(3,)" "(2, 3)"; do
    tag=$([ "$dims" = "(3,)" ] && echo direct2d || echo factored2d)
    python -c "
import sys, sim.mpm as m
m._FACTORED_TRANSFERS = $dims
from benchmarks.sim_solver import main
sys.argv = ['sim_solver', '--scene', 'world', '--envs', '32', '--seconds', '1.0', '--out', '$OUT/${tag}_$r.json']
main()" 2>&1 | grep -E "^ +32 " | sed "s/^/$tag $r /"
  done
done
