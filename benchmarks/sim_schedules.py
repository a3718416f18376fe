"""Cup schedules of a batch (the CPU-side part of executing it) in one thread, on threads, and in
worker processes, timed in one run:

    python -m benchmarks.sim_schedules [--n 512] [--actions 6] [--workers N] [--rounds 2] [--out FILE]

Why: on a 16-core GPU box the schedules of 2048 random trajectories take 46 % of their execution on
16 threads, about what one thread takes (BENCHMARKS.md, "GPU"); large batches compute them in spawned
processes (``sim.execute.SCHEDULE_PROCESS_MIN_BATCH``). This measures the
three ways on the same batch (the execute benchmark's generator: random target-world trajectories),
checks that they give the same schedules, and reports trajectories/s and the ratios. The process
pool's start-up (spawn, imports) is timed apart: the executor keeps its pool for later batches.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from typing import Sequence

import numpy as np

from benchmarks._cli import report
from planner.pool import available_cpus


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.sim_schedules", description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=512, help="trajectories in the batch")
    ap.add_argument("--actions", type=int, default=6, help="random actions per trajectory")
    ap.add_argument("--workers", type=int, default=None, help="threads / processes (default: the executor's rule)")
    ap.add_argument("--rounds", type=int, default=2, help="timed rounds of each way, alternating (median)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="write the result as JSON here")
    args = ap.parse_args(argv)
    if args.n < 1 or args.actions < 1 or args.rounds < 1 or (args.workers is not None and args.workers < 1):
        ap.error("--n, --actions, --rounds and --workers must be >= 1")

    import sim.execute as execute
    from sim.execute import PouringExecutor
    from sim.problems import sample_problems
    from sim.skills import random_actions, validate_actions
    from sim.world import WorldConfig

    cfg = WorldConfig.load()
    rng = np.random.default_rng(args.seed)
    probs = sample_problems(cfg, args.n, args.seed)
    starts = np.array([p.start[:3] for p in probs])
    specs = [cfg.scene("target", s, p.plant_jitter) for s, p in zip(starts, probs)]
    acts = validate_actions(cfg, [random_actions(cfg, args.actions, rng) for _ in probs])
    cpus = available_cpus()
    workers = args.workers or min(execute.SCHEDULE_THREADS, cpus)

    ex = PouringExecutor(cfg)
    ways = {
        "one thread": dict(SCHEDULE_THREADS=1, SCHEDULE_PROCESS_MIN_BATCH=10**9),
        "threads": dict(SCHEDULE_THREADS=workers, SCHEDULE_PROCESS_MIN_BATCH=10**9),
        "processes": dict(SCHEDULE_THREADS=workers, SCHEDULE_PROCESS_MIN_BATCH=1, SCHEDULE_PROCESS_MIN_CPUS=1),
    }

    def run(way: str):
        for k, v in ways[way].items():
            setattr(execute, k, v)
        t = time.perf_counter()
        out = ex._schedules(specs, starts, acts)
        return out, time.perf_counter() - t

    t = time.perf_counter()
    run("processes")  # start the pool: spawn + imports
    start_up = time.perf_counter() - t
    times: dict[str, list[float]] = {w: [] for w in ways}
    results = {}
    for _ in range(args.rounds):
        for way in ways:
            results[way], dt = run(way)
            times[way].append(dt)
    ex.close()
    ref = results["one thread"]
    same = all(
        all(
            np.array_equal(a.poses, b.poses) and a.action_end == b.action_end and a.stuck_on == b.stuck_on
            for a, b in zip(ref, results[w])
        )
        for w in ways
    )
    med = {w: statistics.median(v) for w, v in times.items()}
    ticks = int(sum(len(s.poses) for s in ref))
    result = {
        "n": args.n,
        "actions": args.actions,
        "workers": workers,
        "cpus": cpus,
        "rounds": args.rounds,
        "seconds": med,
        "seconds_all": times,
        "trajectories_per_second": {w: args.n / s for w, s in med.items()},
        "speedup_over_one_thread": {w: med["one thread"] / s for w, s in med.items()},
        "process_pool_start_up_seconds": start_up,
        "identical": same,
        "schedule_ticks": ticks,
        "load_average_1min": os.getloadavg()[0],
    }
    rows = [(w, f"{med[w]:.2f} s", f"{args.n / med[w]:.0f} traj/s", f"{med['one thread'] / med[w]:.2f}x") for w in ways]
    lines = [
        f"{args.n} random target-world trajectories x {args.actions} actions ({ticks} schedule ticks), "
        f"{workers} workers on {cpus} CPUs, median of {args.rounds}:"
    ]
    lines += [f"  {w:<11} {a:>9} {b:>14} {c:>7}" for w, a, b, c in rows]
    lines += [f"  process pool start-up {start_up:.1f} s (once per executor); identical schedules: {same}"]
    report("\n".join(lines), result, args.out)
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
