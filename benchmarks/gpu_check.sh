#!/bin/bash
# The GPU checks in one go, each bounded in time, each writing its JSON or log to OUTDIR:
#
#     bash benchmarks/gpu_check.sh OUTDIR [WORKERS]
#     STEPS="execute_b2048 planner_pool paper" PAPER_SECONDS=300 bash benchmarks/gpu_check.sh OUTDIR 16
#
# Why one script: a lent GPU machine is held for minutes, not hours (see BENCHMARKS.md, "GPU"); this
# runs, in order of importance, what only a GPU can measure, so that a cut-off run still returns the
# first results. All steps take about 14 minutes on an H100/H200 box with 16 cores; STEPS picks some
# (names below, in the order given). Run from the repository root.
#   execute_b32    executing 32 x 6 random target-world trajectories (finished environments frozen against
#                  every environment to the end, with the share of each stage: simulation should be most of it)
#   execute_b512   the same at B = 512 and B = 2048 (throughput: trajectories/s, environment-ticks/s; their
#   execute_b2048  schedules in worker processes)
#   schedules      the CPU-side schedules of 1024 trajectories in one thread, on threads and in processes
#   check_arch     CPU/GPU agreement on 8 random trajectories and the scripted pours
#   planner_pool   planning in WORKERS processes (default 16) against in-process, on the quick experiment's batches
#   paper          the paper protocol (5 methods x 4 seeds, lockstep, WORKERS planner processes, the GPU
#                  simulator) for PAPER_SECONDS (default 300), then its runs' CSVs and logs packed into
#                  OUTDIR/paper_runs.tgz: each run's results.csv has the time of every phase per round
set -u
out=${1:?usage: bash benchmarks/gpu_check.sh OUTDIR [WORKERS]}
workers=${2:-16}
steps=${STEPS:-execute_b32 execute_b512 execute_b2048 schedules check_arch planner_pool paper}
paper_seconds=${PAPER_SECONDS:-300}
paper_args=${PAPER_ARGS:-experiment=paper seeds=[0,1,2,3]}
arch=${ARCH:-gpu}  # ARCH=cpu tries the script on a machine without a GPU
allowed="execute_b32 execute_b512 execute_b2048 schedules check_arch planner_pool paper"
for s in $steps; do
    [[ " $allowed " == *" $s "* ]] || { echo "STEPS: unknown step '$s' (allowed: $allowed)"; exit 2; }
done
mkdir -p "$out"
export PYTHONUNBUFFERED=1
t0=$(date +%s)
run_step() {  # run_step SECONDS NAME COMMAND...: run with a time limit, log to OUTDIR/NAME.log, say how long it took
    local limit=$1 name=$2
    shift 2
    timeout --kill-after=10 "$limit" "$@" >"$out/$name.log" 2>&1
    echo "== $name: exit $? after $(( $(date +%s) - t0 )) s"
    grep -v "tick/s\|it/s" "$out/$name.log" | tail -12
    # a step cut off by its limit must not leave planner workers or schedule processes behind to slow the next
    pkill -f "multiprocessing.spawn" 2>/dev/null
    sleep 1
}
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"
echo "CPUs: $(nproc)"
for s in $steps; do
    case $s in
    execute_b32) run_step 100 execute_b32 python -m benchmarks.sim_execute --arch "$arch" --n 32 --out "$out/execute_gpu_b32.json" ;;
    execute_b512) run_step 80 execute_b512 python -m benchmarks.sim_execute --arch "$arch" --n 512 --no-compare --out "$out/execute_gpu_b512.json" ;;
    execute_b2048) run_step 140 execute_b2048 python -m benchmarks.sim_execute --arch "$arch" --n 2048 --no-compare --out "$out/execute_gpu_b2048.json" ;;
    schedules) run_step 60 schedules python -m benchmarks.sim_schedules --n 1024 --rounds 1 --out "$out/schedules_1024.json" ;;
    check_arch) run_step 75 check_arch python -m benchmarks.check_arch --arch "$arch" --reference cpu --n 8 --out "$out/check_arch_gpu.json" ;;
    planner_pool) run_step 150 planner_pool python -m benchmarks.planner_pool --workers "$workers" --repeat 1 --out "$out/planner_pool_$workers.json" ;;
    paper)
        rm -rf /tmp/gpu_check_paper
        # shellcheck disable=SC2086  # paper_args is a list of Hydra overrides
        run_step "$paper_seconds" paper python -m active.run $paper_args world.sim.arch="$arch" planner.workers="$workers" \
            progress=false wandb.mode=disabled hydra.run.dir=/tmp/gpu_check_paper
        tar czf "$out/paper_runs.tgz" --exclude='*.pt' --exclude='*.npz' -C /tmp gpu_check_paper
        echo "== paper runs packed: $(du -h "$out/paper_runs.tgz" | cut -f1)" ;;
    esac
done
