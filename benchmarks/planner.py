"""Planner speed benchmark: ``python -m benchmarks.planner [--out bench.json]``.

Measures, with the stand-in dynamics model (analytic pouring + an 8-128-128-5 MLP, see
:mod:`tests.doubles.standins`) and an MDE fitted on ``--mde-points`` synthetic points:

1. raw batched throughput of dynamics + MDE (rows/s per batch size);
2. single-candidate planning over ``--problems`` problems of the default world
   (``task.problems``): propagations/s (model + MDE evaluations per second of planning), OMPL
   expansions/s, median plan time, found rate;
3. the same with batching switched off (batch size 1: one model + MDE call per propagation),
   to show what batching buys;
4. full candidate sets (N = ``--candidates``) for ``--candidate-problems`` problems.

The MDE is ``mde.GPMDE`` when importable and fittable (``--mde auto``, the
default) and otherwise the :class:`~tests.doubles.standins.StandInGPMDE`; the table says which. The
deviation labels are synthetic (:func:`~tests.doubles.standins.synthetic_deviation_dataset`), so found
rates here say nothing about the real task; only the timings are the point.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from benchmarks._cli import report
from planner.config import PlannerConfig
from planner.rrt import Planner, _Evaluator
from task.problems import sample_problems
from task.threads import torch_threads
from tests.doubles.standins import StandInGPMDE, StandInMLPDynamics, synthetic_deviation_dataset

TARGET_PROPS_PER_S = 2000.0
TARGET_MEDIAN_PLAN_S = 1.0


def build_mde(kind: str, n_points: int, seed: int, config: PlannerConfig) -> tuple[Any, dict[str, Any]]:
    """Fit the MDE used by the bench; returns it and a description (which one, fit time)."""
    X, d = synthetic_deviation_dataset(n_points, np.random.default_rng(seed), config)
    info: dict[str, Any] = {"points": int(n_points)}
    if kind in ("auto", "real"):
        try:
            from mde import GPMDE  # type: ignore[import-not-found]

            t = time.perf_counter()
            mde = GPMDE().fit(torch.as_tensor(X), torch.as_tensor(d))
            info.update(kind="mde.GPMDE", fit_s=time.perf_counter() - t)
            return mde, info
        except Exception as e:  # noqa: BLE001 - any failure means "use the stand-in" in auto mode
            if kind == "real":
                raise
            info["real_mde_unavailable"] = f"{type(e).__name__}: {e}"[:300]
    t = time.perf_counter()
    mde = StandInGPMDE(seed=seed).fit(X, d)
    info.update(kind="tests.doubles.standins.StandInGPMDE (stand-in)", fit_s=time.perf_counter() - t)
    return mde, info


def batch_throughput(
    dynamics: Any, mde: Any, config: PlannerConfig, sizes: Sequence[int], seconds: float = 0.5
) -> dict[int, float]:
    """Rows per second of one dynamics + MDE evaluation call, per batch size."""
    ev = _Evaluator(dynamics, mde, Planner(dynamics, mde, config).sampler)
    rng = np.random.default_rng(0)
    out = {}
    with torch_threads(config.torch_threads):
        for k in sizes:
            s = np.tile([0.4, 0.1, 0.0, 1.0, 0.0], (k, 1))
            a = ev.sampler.sample(k, rng)
            ev.evaluate(s, a)
            n, t0 = 0, time.perf_counter()
            while time.perf_counter() - t0 < seconds:
                ev.evaluate(s, a)
                n += 1
            out[int(k)] = k * n / (time.perf_counter() - t0)
    return out


def plan_problems(planner: Planner, problems: list, seed: int) -> dict[str, Any]:
    runs = []
    for i, pr in enumerate(problems):
        r = planner.plan(pr.start, pr.goal, seed=seed + i)
        runs.append(r.stats)
    total_t = sum(s.time_s for s in runs)
    times = [s.time_s for s in runs]
    found_times = [s.time_s for s in runs if s.found]
    return {
        "runs": len(runs),
        "found_rate": sum(s.found for s in runs) / len(runs),
        "median_plan_s": statistics.median(times),
        "median_plan_s_found": statistics.median(found_times) if found_times else None,
        "p90_plan_s": float(np.percentile(times, 90)),
        "propagations": int(sum(s.propagations for s in runs)),
        "mde_evaluations": int(sum(s.mde_evaluations for s in runs)),
        "expansions": int(sum(s.expansions for s in runs)),
        "tree_nodes": int(sum(s.tree_size for s in runs)),
        "propagations_per_s": sum(s.propagations for s in runs) / total_t,
        "mde_evaluations_per_s": sum(s.mde_evaluations for s in runs) / total_t,
        "expansions_per_s": sum(s.expansions for s in runs) / total_t,
        "rejected_fraction": sum(s.rejected for s in runs) / max(1, sum(s.mde_evaluations for s in runs)),
        "terminations": {k: sum(s.termination == k for s in runs) for k in sorted({s.termination for s in runs})},
    }


def run(
    problems: int = 30,
    seed: int = 0,
    mde: str = "auto",
    mde_points: int = 1200,
    beta: float = 2.0,
    d_max: float = 0.07,
    candidates: int = 9,
    candidate_problems: int = 5,
    unbatched_problems: int = 10,
    throughput_seconds: float = 0.5,
    time_budget: float | None = None,
    config: PlannerConfig | None = None,
    dynamics_path: str | None = None,
    known_obstacles: bool = False,
) -> dict[str, Any]:
    config = (config or PlannerConfig()).replace(beta=beta, d_max=d_max, n_candidates=candidates)
    if time_budget is not None:
        config = config.replace(time_budget=time_budget)
    if dynamics_path is None:
        dynamics = StandInMLPDynamics(seed=seed)
        dyn_info = "tests.doubles.standins.StandInMLPDynamics (stand-in: analytic + 8-128-128-5 MLP)"
    else:  # a trained f_hat checkpoint; imported here only, the planner itself needs no dynamics package
        from dynamics import LearnedDynamics

        dynamics = LearnedDynamics.load(dynamics_path)
        dyn_info = f"dynamics.LearnedDynamics ({dynamics_path})"
    from sim.world import WorldConfig

    world = WorldConfig.load()  # the default world: its problems (task.problems), and its obstacles if known
    if known_obstacles:  # as the experiment runs it: contacts with the target cup and tank predicted
        from dynamics import ContactAwareDynamics

        dynamics = ContactAwareDynamics(dynamics, world)
        dyn_info += " + ContactAwareDynamics (default world)"
    model, mde_info = build_mde(mde, mde_points, seed, config)
    probs = sample_problems(world, problems, np.random.default_rng(seed + 1))
    planner = Planner(dynamics, model, config)
    planner.plan(probs[0].start, probs[0].goal, seed=10**6)  # warm-up (lazy torch/OMPL init)

    result: dict[str, Any] = {
        "machine": {
            "python": platform.python_version(),
            "torch": torch.__version__,
            "cpus": _cpu_count(),
            "torch_threads_planning": config.torch_threads,
        },
        "dynamics": dyn_info,
        "mde": mde_info,
        "precondition": {"beta": beta, "d_max": d_max},
        "config": config.to_dict(),
        "batch_rows_per_s": batch_throughput(dynamics, model, config, (1, 16, 64, 256), throughput_seconds),
        "planning": plan_problems(planner, probs, seed),
    }
    if unbatched_problems > 0:
        unbatched = Planner(dynamics, model, config.replace(batch_min=1, batch_max=1))
        result["planning_unbatched"] = plan_problems(unbatched, probs[:unbatched_problems], seed)
    if candidate_problems > 0:
        times, counts, props = [], [], []
        for i, pr in enumerate(probs[:candidate_problems]):
            cs = planner.plan_candidates(pr.start, pr.goal, seed=seed + 1000 + i)
            times.append(cs.time_s)
            counts.append(len(cs))
            props.append(cs.propagations)
        result["candidates"] = {
            "n": candidates,
            "problems": len(times),
            "median_time_s": statistics.median(times),
            "mean_found": float(np.mean(counts)),
            "propagations_per_s": sum(props) / sum(times),
        }
    p = result["planning"]
    result["targets"] = {
        "propagations_per_s": {
            "target": TARGET_PROPS_PER_S,
            "value": p["propagations_per_s"],
            "met": p["propagations_per_s"] >= TARGET_PROPS_PER_S,
        },
        "median_plan_s": {
            "target": TARGET_MEDIAN_PLAN_S,
            "value": p["median_plan_s"],
            "met": p["median_plan_s"] <= TARGET_MEDIAN_PLAN_S,
        },
    }
    return result


def _cpu_count() -> int | None:
    import os

    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - non-Linux
        return os.cpu_count()


def format_table(r: dict[str, Any]) -> str:
    p = r["planning"]
    rows = [
        ("dynamics model", r["dynamics"]),
        ("MDE", f"{r['mde']['kind']}, {r['mde']['points']} points, fit {r['mde']['fit_s']:.1f} s"),
        ("precondition", f"mu + {r['precondition']['beta']} sigma < {r['precondition']['d_max']}"),
        ("torch threads (planning)", str(r["machine"]["torch_threads_planning"])),
    ]
    if "real_mde_unavailable" in r["mde"]:
        rows.append(("real MDE not used", r["mde"]["real_mde_unavailable"]))
    for k, v in r["batch_rows_per_s"].items():
        rows.append((f"raw model+MDE rows/s, batch {k}", f"{v:,.0f}"))
    rows += [
        ("problems (1 candidate each)", str(p["runs"])),
        ("found rate", f"{p['found_rate']:.2f}"),
        ("propagations/s (dynamics rows)", f"{p['propagations_per_s']:,.0f}"),
        ("MDE evaluations/s (rows past cheap checks)", f"{p['mde_evaluations_per_s']:,.0f}"),
        ("OMPL expansions/s (propagator calls)", f"{p['expansions_per_s']:,.0f}"),
        ("median plan time", f"{p['median_plan_s']:.3f} s"),
        (
            "median plan time, found only",
            "-" if p["median_plan_s_found"] is None else f"{p['median_plan_s_found']:.3f} s",
        ),
        ("90th percentile plan time", f"{p['p90_plan_s']:.3f} s"),
        ("rejected by precondition", f"{p['rejected_fraction']:.2f} of MDE-evaluated rows"),
        ("terminations", ", ".join(f"{k}={v}" for k, v in p["terminations"].items())),
    ]
    if "planning_unbatched" in r:
        u = r["planning_unbatched"]
        rows += [
            (f"UNBATCHED ({u['runs']} problems) propagations/s", f"{u['propagations_per_s']:,.0f}"),
            ("UNBATCHED median plan time", f"{u['median_plan_s']:.3f} s (found rate {u['found_rate']:.2f})"),
            ("UNBATCHED OMPL expansions/s", f"{u['expansions_per_s']:,.0f}"),
        ]
    if "candidates" in r:
        c = r["candidates"]
        rows += [
            (
                f"candidate sets (N={c['n']}, {c['problems']} problems)",
                f"median {c['median_time_s']:.2f} s per problem",
            ),
            ("candidates found per problem", f"{c['mean_found']:.1f} of {c['n']}"),
        ]
    for name, t in r["targets"].items():
        op = ">=" if name == "propagations_per_s" else "<="
        rows.append((f"TARGET {name} {op} {t['target']:g}", f"{'MET' if t['met'] else 'NOT MET'} ({t['value']:,.3f})"))
    w = max(len(a) for a, _ in rows)
    return "\n".join(f"{a:<{w}}  {b}" for a, b in rows)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.planner", description=__doc__.split("\n\n")[0])
    ap.add_argument("--problems", type=int, default=30, help="problems planned with one candidate each")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--mde",
        choices=("auto", "real", "standin"),
        default="auto",
        help="auto: mde.GPMDE if it works, else the stand-in GP",
    )
    ap.add_argument("--mde-points", type=int, default=1200)
    ap.add_argument("--beta", type=float, default=2.0)
    ap.add_argument("--d-max", type=float, default=0.07)
    ap.add_argument("--candidates", type=int, default=9)
    ap.add_argument("--candidate-problems", type=int, default=5)
    ap.add_argument("--unbatched-problems", type=int, default=10)
    ap.add_argument("--throughput-seconds", type=float, default=0.5, help="time per raw-throughput measurement")
    ap.add_argument("--time-budget", type=float, default=None, help="override the per-candidate time budget (s)")
    ap.add_argument(
        "--dynamics",
        default=None,
        metavar="CHECKPOINT",
        help="a trained dynamics.LearnedDynamics checkpoint (e.g. .cache/dynamics/model-*/model.pt) "
        "instead of the stand-in",
    )
    ap.add_argument(
        "--known-obstacles",
        action="store_true",
        help="wrap the model with dynamics.ContactAwareDynamics, as experiment.known_obstacles does",
    )
    ap.add_argument("--out", type=Path, default=None, help="write the full result as JSON here")
    args = ap.parse_args(argv)
    if args.problems < 1:
        ap.error("--problems must be >= 1")
    r = run(
        problems=args.problems,
        seed=args.seed,
        mde=args.mde,
        mde_points=args.mde_points,
        beta=args.beta,
        d_max=args.d_max,
        candidates=args.candidates,
        candidate_problems=args.candidate_problems,
        unbatched_problems=args.unbatched_problems,
        throughput_seconds=args.throughput_seconds,
        time_budget=args.time_budget,
        dynamics_path=args.dynamics,
        known_obstacles=args.known_obstacles,
    )
    report(format_table(r), r, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
