#!/bin/bash
# The GPU checks in one go, each bounded in time, each writing its JSON to OUTDIR:
#
#     bash benchmarks/gpu_check.sh OUTDIR [WORKERS]
#
# Why one script: a lent GPU machine is held for minutes, not hours (see BENCHMARKS.md, "GPU"); this
# runs, in order of importance, what only a GPU can measure, so that a cut-off run still returns the
# first results. About 10 minutes on an H100/H200 box with 16 cores; run from the repository root.
#   1. executing 32 x 6 random target-world trajectories (finished environments frozen against
#      every environment to the end, with the share of each stage: simulation should be most of it),
#   2. the same at B = 512 and B = 2048 (throughput: trajectories/s, environment-ticks/s), and the
#      CPU-side schedules of 1024 trajectories in one thread, on threads and in processes,
#   3. CPU/GPU agreement on 8 random trajectories and the scripted pours,
#   4. planning in WORKERS processes (default 16) against in-process, on the quick experiment's batches.
set -u
out=${1:?usage: bash benchmarks/gpu_check.sh OUTDIR [WORKERS]}
workers=${2:-16}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
t0=$(date +%s)
step() {  # step SECONDS NAME COMMAND...: run with a time limit, log to OUTDIR/NAME.log, say how long it took
    local limit=$1 name=$2
    shift 2
    timeout "$limit" "$@" >"$out/$name.log" 2>&1
    echo "== $name: exit $? after $(( $(date +%s) - t0 )) s"
    grep -v "tick/s\|it/s" "$out/$name.log" | tail -12
}
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"
step 100 execute_b32 python -m benchmarks.sim_execute --arch gpu --n 32 --out "$out/execute_gpu_b32.json"
step 60 execute_b512 python -m benchmarks.sim_execute --arch gpu --n 512 --no-compare --out "$out/execute_gpu_b512.json"
step 140 execute_b2048 python -m benchmarks.sim_execute --arch gpu --n 2048 --no-compare --out "$out/execute_gpu_b2048.json"
step 60 schedules python -m benchmarks.sim_schedules --n 1024 --rounds 1 --out "$out/schedules_1024.json"
step 75 check_arch python -m benchmarks.check_arch --arch gpu --reference cpu --n 8 --out "$out/check_arch_gpu.json"
step 150 planner_pool python -m benchmarks.planner_pool --workers "$workers" --repeat 1 --out "$out/planner_pool_$workers.json"
