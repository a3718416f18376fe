"""Planning in worker processes vs in-process, on the experiment's own batches:
``python -m benchmarks.planner_pool [--workers 2] [--mde CHECKPOINT]
[--out benchmarks/results/planner_pool.json] [overrides]``.

Why: planning is the largest cost of ``python -m active.run`` and every planner run is
single-threaded; :class:`planner.pool.PlanPool` spreads a batch over processes. This measures
what that buys on this machine, with the model and batches the experiment uses:

* the cached dynamics model of the composed config (``dynamics.load_or_train``; trained on first
  use, ~6 min), wrapped with the known obstacles as ``experiment.known_obstacles`` says;
* the planner config of the run (``active.planner_setup.build_planner_config``: world skill limits,
  ``experiment.planner_propagation_budget``, 10,000 for experiment=quick);
* batch ``test``: the run's test problems (``experiment.test_problems``), one plan each with
  beta_test and the run's per-problem seeds; batch ``train``: one refit chunk of training
  problems (``experiment.refit_every``), ``experiment.candidates`` candidates each, beta of
  iteration ``--iteration``;
* the MDE: none, or ``--mde`` = a saved MDE (``mde.GPMDE`` or ``mde.GroupedMDE``, e.g. ``mde_iterNNN.pt`` of a run).

Both batches run in-process (workers=1) and with ``--workers`` processes, ``--repeat`` times each
in alternating order (medians reported), after one warm-up plan per process; the worker start-up
(spawn, imports, model transfer) and the warm-up are timed separately from the batches, and the
results of every repeat are compared bit for bit. The CPU capacity of ``--workers`` concurrent
processes (a pure-Python spin loop, before and after) is the ceiling of the speedup: a virtual
machine's vCPUs may deliver less than one core each. Extra arguments are Hydra overrides of the experiment's config
(default ``experiment=quick``), e.g. ``experiment.planner_propagation_budget=5000``.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import torch

from benchmarks._cli import report
from planner.pool import PlanPool, PlanRequest, available_cpus
from planner.results import CandidateSet, PlanResult


def fingerprint(r: Any) -> Any:
    """Everything deterministic about a planner result (its wall-clock times left out)."""
    if isinstance(r, CandidateSet):
        return ("set", [fingerprint(t) for t in r.candidates], [fingerprint(x) for x in r.runs])
    if isinstance(r, PlanResult):
        s = r.stats
        return (
            "plan",
            fingerprint(r.trajectory),
            s.found,
            s.propagations,
            s.mde_evaluations,
            s.expansions,
            s.rejected,
            s.tree_size,
            s.termination,
            s.seed,
            s.best_goal_distance,
        )
    if r is None:
        return None
    return tuple(getattr(r, k).tobytes() for k in ("actions", "states", "mu", "sigma"))


def experiment_batches(cfg: dict, seed: int, iteration: int) -> tuple[Any, Any, dict[str, list[PlanRequest]], dict]:
    """Dynamics model, planner config and the two request batches exactly as ``active.run`` builds them."""
    from active.loop import requests_at_test
    from active.planner_setup import planning_dynamics
    from active.seeds import derive_seed
    from active.settings import read_settings
    from sim.problems import sample_problems

    settings = read_settings(cfg, method="all")
    exp, world, planner_cfg = settings.exp, settings.world, settings.planner
    t = time.perf_counter()
    dyn = planning_dynamics(settings.dynamics, world, exp)
    info = {"load_s": time.perf_counter() - t, "known_obstacles": exp.known_obstacles}
    test = sample_problems(world, exp.test_problems, derive_seed(seed, "test"), world="target")
    train = sample_problems(
        world, exp.trajectories_per_iteration, derive_seed(seed, "train", iteration), world="target"
    )[: exp.refit_every]
    method = exp.methods[0]
    batches = {
        "test": requests_at_test(test, exp, seed, "test-plan", iteration),
        "train": [
            PlanRequest(
                "candidates",
                p.start,
                p.goal,
                n=exp.candidates,
                beta=exp.beta(iteration),
                d_max=exp.d_max,
                seed=derive_seed(seed, "plan", iteration, k),
            )
            for k, p in enumerate(train)
        ],
    }
    info.update(
        experiment=exp.name,
        train_method=method,
        candidates=exp.candidates,
        propagation_budget=planner_cfg.propagation_budget,
        beta_test=exp.beta_test,
        beta_train=exp.beta(iteration),
    )
    return dyn, planner_cfg, batches, info


_SPIN = "import time\nt = time.perf_counter()\ns = 0\nfor i in range({n}): s += i * i\nprint(time.perf_counter() - t)"


def parallel_capacity(n: int, iterations: int = 10**7) -> float:
    """Cores' worth of throughput ``n`` concurrent CPU-bound processes get here (``n`` on an idle
    ``n``-core machine; less on a shared or throttled one): the ceiling of any speedup ``n`` workers give."""
    cmd = [sys.executable, "-c", _SPIN.format(n=iterations)]
    solo = float(subprocess.run(cmd, capture_output=True, text=True, check=True).stdout)
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True) for _ in range(n)]
    each = [float(p.communicate()[0]) for p in procs]
    return n * solo / statistics.mean(each)


def _runs(results: list) -> int:
    return sum(len(r.runs) if isinstance(r, CandidateSet) else 1 for r in results)


def _found(results: list) -> int:
    return sum(len(r.candidates) if isinstance(r, CandidateSet) else int(r.found) for r in results)


def run(
    overrides: Sequence[str] = (),
    workers: int = 2,
    mde_path: str | None = None,
    seed: int = 0,
    iteration: int = 0,
    repeat: int = 2,
) -> dict[str, Any]:
    from active.run import compose_config

    load_before = os.getloadavg()
    cfg = compose_config(["experiment=quick", *overrides])
    dyn, planner_cfg, batches, info = experiment_batches(cfg, seed, iteration)
    mde, mde_info = None, "none (every transition admissible)"
    if mde_path is not None:
        from mde import load

        mde = load(mde_path)
        mde_info = f"{mde!r} from {mde_path}"
    result: dict[str, Any] = {
        "machine": {
            "python": platform.python_version(),
            "torch": torch.__version__,
            "cpus": available_cpus(),
            "torch_threads_planning": planner_cfg.torch_threads,
        },
        "setup": info,
        "mde": mde_info,
        "workers": workers,
        "overrides": list(overrides),
        "seed": seed,
        "iteration": iteration,
        "batches": {},
    }
    result["parallel_capacity_before"] = parallel_capacity(workers)
    local = PlanPool(dyn, planner_cfg, workers=1)
    warm = [
        PlanRequest("plan", r.start, r.goal, beta=r.beta, d_max=r.d_max, seed=10**6 + i)
        for i, r in enumerate(batches["test"][:workers])
    ]  # one per worker; lazy torch / OMPL set-up
    t = time.perf_counter()
    local.run(warm[:1], mde)
    result["warmup_in_process_s"] = time.perf_counter() - t
    times: dict[str, dict[str, list[float]]] = {name: {"here": [], "pool": []} for name in batches}
    same: dict[str, bool] = {name: True for name in batches}
    want = {}
    preload = [type(mde).__module__] if mde is not None else []
    with PlanPool(dyn, planner_cfg, workers=workers, preload=preload) as pool:
        result["startup_s"] = pool.start()
        if not pool.parallel:
            raise RuntimeError(f"the worker processes did not start: {pool.fallback_reason}")
        t = time.perf_counter()
        pool.run(warm, mde)
        result["warmup_workers_s"] = time.perf_counter() - t
        for rep in range(repeat):  # alternating order: a drift of the machine's speed hits both sides alike
            for name, reqs in batches.items():
                for side in ("here", "pool") if rep % 2 == 0 else ("pool", "here"):
                    t = time.perf_counter()
                    got = (local if side == "here" else pool).run(reqs, mde)
                    times[name][side].append(time.perf_counter() - t)
                    fp = [fingerprint(x) for x in got]
                    if name not in want:
                        want[name] = (fp, got)
                    same[name] &= fp == want[name][0]
        if not pool.parallel:
            raise RuntimeError(f"the worker processes failed during the bench: {pool.fallback_reason}")
    for name, reqs in batches.items():
        here, there = statistics.median(times[name]["here"]), statistics.median(times[name]["pool"])
        res = want[name][1]
        result["batches"][name] = {
            "requests": len(reqs),
            "planner_runs": _runs(res),
            "found": _found(res),
            "in_process_s": here,
            "workers_s": there,
            "speedup": here / there,
            "in_process_s_all": times[name]["here"],
            "workers_s_all": times[name]["pool"],
            "identical": same[name],
        }
    result["parallel_capacity_after"] = parallel_capacity(workers)
    # above ~0 another job shared the machine when the bench started, and the figures are not clean
    result["load_average_1min_before"] = load_before[0]
    return result


def format_table(r: dict[str, Any]) -> str:
    s = r["setup"]
    rows = [
        (
            "machine",
            f"{r['machine']['cpus']} CPUs, torch {r['machine']['torch']}, "
            f"{r['machine']['torch_threads_planning']} torch thread per planner",
        ),
        (
            "setup",
            f"experiment={s['experiment']}, budget {s['propagation_budget']} propagations per run, "
            f"known obstacles {s['known_obstacles']}",
        ),
        ("MDE", r["mde"]),
        ("load average (1 min) at the start", f"{r['load_average_1min_before']:.2f} (> ~0.3: other jobs ran)"),
        (
            f"CPU capacity of {r['workers']} processes",
            f"{r['parallel_capacity_before']:.2f} / "
            f"{r['parallel_capacity_after']:.2f} cores (before / after; "
            f"the ceiling of the speedup)",
        ),
        (f"worker start-up ({r['workers']} processes, spawn)", f"{r['startup_s']:.1f} s (once per run)"),
        (
            "first plans (warm-up)",
            f"in-process {r['warmup_in_process_s']:.2f} s, workers {r['warmup_workers_s']:.2f} s (once per run)",
        ),
    ]
    for name, b in r["batches"].items():
        what = (
            f"{b['requests']} test plans"
            if name == "test"
            else f"{b['requests']} problems x {s['candidates']} candidates"
        )
        rows += [
            (f"batch {name}: {what}", f"{b['planner_runs']} planner runs, {b['found']} found"),
            (
                "  in-process (workers=1), median",
                f"{b['in_process_s']:.2f} s  ({', '.join(f'{x:.2f}' for x in b['in_process_s_all'])})",
            ),
            (
                f"  workers={r['workers']}, median",
                f"{b['workers_s']:.2f} s  "
                f"({', '.join(f'{x:.2f}' for x in b['workers_s_all'])})  "
                f"speedup x{b['speedup']:.2f}",
            ),
            ("  results identical (every repeat)", "yes" if b["identical"] else "NO"),
        ]
    w = max(len(a) for a, _ in rows)
    return "\n".join(f"{a:<{w}}  {b}" for a, b in rows)


def add_batch_arguments(ap: argparse.ArgumentParser, iteration: int = 0) -> None:
    """The options of a benchmark that plans the experiment's own batches (:func:`experiment_batches`)."""
    ap.add_argument(
        "--mde",
        default=None,
        metavar="CHECKPOINT",
        help="a saved MDE, e.g. a run's mde_iterNNN.pt (default: none, model-only planning)",
    )
    ap.add_argument("--seed", type=int, default=0, help="the run seed the problems and plan seeds derive from")
    ap.add_argument(
        "--iteration", type=int, default=iteration, help="the iteration the plan seeds and training beta are of"
    )
    ap.add_argument("--repeat", type=int, default=2, help="timed repeats of each batch and path (median reported)")
    ap.add_argument("--out", type=Path, default=None, help="write the result as JSON here")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of the experiment config (default experiment=quick)")


def check_batch_arguments(ap: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse bad values of :func:`add_batch_arguments`' options before any compute."""
    if args.repeat < 1:
        ap.error("--repeat must be >= 1")
    if args.mde is not None and not Path(args.mde).is_file():
        ap.error(f"--mde {args.mde}: no such file")


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.planner_pool", description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=2, help="worker processes to compare with in-process planning")
    add_batch_arguments(ap, iteration=0)
    args = ap.parse_args(argv)
    if args.workers < 2:
        ap.error("--workers must be >= 2 (workers=1 is the in-process baseline, always measured)")
    check_batch_arguments(ap, args)
    r = run(
        args.overrides,
        workers=args.workers,
        mde_path=args.mde,
        seed=args.seed,
        iteration=args.iteration,
        repeat=args.repeat,
    )
    report(format_table(r), r, args.out)
    return 0 if all(b["identical"] for b in r["batches"].values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
