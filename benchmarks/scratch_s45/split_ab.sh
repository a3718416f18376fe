#!/bin/bash
# Scratch (session 45). Needs the older code in a worktree: git worktree add /work/wt45old 59e9769
# (session 44's head), and this checkout at /work/main.
# A/B: the split path before (HEAD, /work/wt45old) and after (working tree, /work/main), alternating runs
for r in 1 2; do
  for side in old new; do
    d=/work/main; [ $side = old ] && d=/work/wt45old
    (cd $d && python -m benchmarks.sim_split --dx 0.01 0.0125 0.015 --substeps 600 1200 2000 --rounds 3 --out /tmp/s45_ab_${side}_$r.json 2>&1 | tail -3 | sed "s/^/$side $r /")
  done
done
