#!/bin/bash
# Scratch (session 45). Needs the older code in a worktree: git worktree add /work/wt45old 59e9769
# (session 44's head), and this checkout at /work/main.
# one-task B = 1 3D dam break (one thread): the direct transfers (session 44's head, /work/wt45old) against the factored ones (/work/main), alternating
for r in 1 2 3; do
  for side in old new; do
    d=/work/main; [ $side = old ] && d=/work/wt45old
    (cd $d && TI_CPU_MAX_NUM_THREADS=1 PYTHONPATH=$d python /work/main/benchmarks/scratch_s45/dambreak_b1.py 1500 2>&1 | tail -1 | sed "s/^/$side $r /")
  done
done
