"""Where plans of the learned model alone go wrong, step by step:
``python -m benchmarks.plan_errors [--world source] [--problems 30] [--out FILE] [overrides]``.

Why: a plan of the model alone, executed where the model was trained (the ladder's source rung), can
miss its goal by more than the pour's scatter and the model's average error explain: a planner picks
the pours the model gets wrong in its favour. This plans the ladder's source-rung
problems (same seeds), executes the plans, and for every executed step compares the model's
one-step prediction from the *executed* state (what an MDE label measures) with what happened,
grouped by skill and by the pour's order in the plan (the first pour of a plan starts from a full
cup, later ones from a partly empty, tilted-back cup). Prints a table, writes JSON.

It also asks how far any model could get with these plans: a plan is accepted as soon as its
predicted final state lies within the goal band, so its predicted fraction sits anywhere in the band.
If the outcome of a plan scattered as N(prediction, s^2) around a *perfect* prediction (s: the pour
scatter the ladder's reproducibility rung measures), it would reach the goal with probability
P(|offset + e| < tol); ``--scatter`` lists the s to evaluate (default 0.035, 0.017 and 0.010: the
continuous world's sub-cell scatter, the grid-aligned world's, and the reproducibility target), averaged
over the found plans' own offsets.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from benchmarks._cli import report


def perfect_model_success(offsets: ArrayLike, tol: float, scatter: float) -> float:
    """Mean over plans of P(|offset + e| <= tol), e ~ N(0, scatter^2): how often plans whose predicted
    final fraction lies ``offsets`` from the goal would reach a band of +-``tol`` if the prediction were
    exact and only the outcome scattered."""
    from scipy.stats import norm

    o = np.asarray(offsets, float)
    return float(np.mean(norm.cdf((tol - o) / scatter) - norm.cdf((-tol - o) / scatter)))


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--world", choices=("source", "target"), default="source")
    ap.add_argument("--problems", type=int, default=30)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument(
        "--scatter",
        type=float,
        nargs="+",
        default=[0.035, 0.017, 0.010],
        help="outcome std s of a perfect model's plans (the ladder's reproducibility max_std)",
    )
    ap.add_argument("overrides", nargs="*")
    args = ap.parse_args(argv)
    if any(not s > 0 for s in args.scatter):
        ap.error(f"--scatter {args.scatter}: allowed standard deviations > 0")

    import torch

    from active.ladder import execute_plans, plan_all
    from active.planner_setup import planning_dynamics
    from active.run import compose_config
    from active.seeds import derive_seed
    from active.settings import read_settings
    from planner.pool import PlanPool
    from sim.execute import PouringExecutor
    from sim.problems import sample_problems
    from task import state_distance

    cfg = compose_config(list(args.overrides) + ["progress=false"])
    settings = read_settings(cfg, method="all")
    exp, world = settings.exp, settings.world
    dyn = planning_dynamics(settings.dynamics, world, exp)
    seed = int(cfg.get("seed", 0))
    problems = sample_problems(world, args.problems, derive_seed(seed, "ladder-problems", args.world), world=args.world)
    with PlanPool(dyn, settings.planner, settings.workers) as pool:
        plans = plan_all(pool, None, problems, exp, seed, f"model-only-{args.world}")  # the ladder's own plans
    executor = PouringExecutor(world)
    results = execute_plans(executor, args.world, problems, plans)
    executor.close()

    steps = []
    for k, (_plan, res) in enumerate(zip(plans, results)):
        if res is None:
            continue
        pours = 0
        for t, st in enumerate(res.steps):
            kind = "move" if st.a[0] < 0.5 else "pour"
            pours += kind == "pour"
            with torch.no_grad():
                pred = (
                    dyn.predict(
                        torch.as_tensor(st.s[None], dtype=torch.float32),
                        torch.as_tensor(st.a[None], dtype=torch.float32),
                    )
                    .double()
                    .numpy()[0]
                )
            steps.append(
                {
                    "problem": k,
                    "t": t,
                    "kind": kind,
                    "pour_index": pours if kind == "pour" else 0,
                    "v_ctrl_before": float(st.s[3]),
                    "action": st.a.tolist(),
                    "dv_tgt_true": float(st.s_next[4] - st.s[4]),
                    "dv_tgt_pred": float(pred[4] - st.s[4]),
                    "err_v_tgt": float(pred[4] - st.s_next[4]),
                    "err_v_ctrl": float(pred[3] - st.s_next[3]),
                    "label": float(state_distance(pred[None], st.s_next[None], world.distance_weights)[0]),
                }
            )
    done = [r for r in results if r is not None]
    plan_rows = [
        {
            "problem": k,
            "goal": problems[k].goal,
            "final_v_tgt": float(r.states[-1, 4]),
            "planned_v_tgt": float(plans[k].states[-1, 4]),
            "n_actions": len(r.steps),
            "n_pours": int(sum(st.a[0] >= 0.5 for st in r.steps)),
            "goal_reached": bool(r.goal_reached),
            "spill": r.final_spill,
        }
        for k, r in enumerate(results)
        if r is not None
    ]
    groups = {
        "move": [s for s in steps if s["kind"] == "move"],
        "first pour": [s for s in steps if s["pour_index"] == 1],
        "later pours": [s for s in steps if s["pour_index"] > 1],
        "pours that moved water (|dv_tgt| > 0.02)": [
            s for s in steps if s["kind"] == "pour" and abs(s["dv_tgt_true"]) > 0.02
        ],
    }
    summary = {}
    lines = [
        f"{args.world} world: {len(done)} of {args.problems} plans found and executed, "
        f"{sum(p['goal_reached'] for p in plan_rows)} reached the goal",
        f"{'steps':<42} {'n':>4} {'mean err v_tgt':>15} {'mean |err v_tgt|':>17} {'median label':>13} {'labels > d_max':>15}",  # noqa: E501 (a table row's format reads best on one line)
    ]
    for name, g in groups.items():
        if not g:
            continue
        e = np.array([s["err_v_tgt"] for s in g])
        lab = np.array([s["label"] for s in g])
        summary[name] = {
            "n": len(g),
            "mean_err_v_tgt": float(e.mean()),
            "mean_abs_err_v_tgt": float(np.abs(e).mean()),
            "median_label": float(np.median(lab)),
            "labels_over_d_max": float((lab > exp.d_max).mean()),
        }
        r = summary[name]
        lines.append(
            f"{name:<42} {r['n']:4d} {r['mean_err_v_tgt']:+15.3f} {r['mean_abs_err_v_tgt']:17.3f} "
            f"{r['median_label']:13.3f} {r['labels_over_d_max']:15.2f}"
        )
    npours = np.array([p["n_pours"] for p in plan_rows])
    ok = np.array([p["goal_reached"] for p in plan_rows])
    for m in sorted(set(npours.tolist())):
        lines.append(
            f"plans with {m} pour(s): {int((npours == m).sum())}, reached the goal {int(ok[npours == m].sum())}"
        )
    tol = float(world.problems["tolerance"])
    offsets = np.array([p["planned_v_tgt"] - p["goal"] for p in plan_rows])
    bound = {str(s): perfect_model_success(offsets, tol, s) for s in args.scatter} if len(offsets) else {}
    if len(offsets):
        lines.append(
            f"planned final v_tgt - goal: mean |offset| {np.abs(offsets).mean():.3f} (goal band +-{tol}); "
            "a perfect model with outcome scatter s would reach the goal with these plans' offsets in: "
            + ", ".join(f"s = {s}: {b:.2f}" for s, b in bound.items())
        )
    result = {
        "world": args.world,
        "overrides": list(args.overrides),
        "summary": summary,
        "plans": plan_rows,
        "steps": steps,
        "perfect_model_success_at_scatter": bound,
        "goal_tolerance": tol,
    }
    report("\n".join(lines), result, args.out)
    return result


if __name__ == "__main__":
    main()
