"""Does gradient refinement of the planned pours (active.refine) raise test-time success?

Plans the run's test problems with the run's final MDE (or with the model alone, ``--no-mde``),
refines each found plan's last pour in the differentiable source-world simulator, executes the
unrefined and the refined plans in the chosen world, and prints the paired comparison.

    python -m benchmarks.refine_check outputs/quick/all/seed0 --method active_balanced --steps 5
    python -m benchmarks.refine_check RUN_DIR --no-mde --world source --problems 20
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

import safeio

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def _last_checkpoint(folder: Path) -> Path | None:
    found = sorted(folder.glob("mde_iter*.pt"))
    return found[-1] if found else None


def run_check(
    run_dir: Path,
    method: str | None,
    steps: int,
    lr: float,
    world_name: str,
    n_problems: int | None,
    use_mde: bool,
    progress: bool = True,
) -> dict:
    import mde as mde_pkg
    from active.planner_setup import planning_dynamics
    from active.refine import refine_plans
    from active.seeds import derive_seed
    from active.settings import read_settings
    from planner import Planner
    from sim.problems import sample_problems
    from sim.world import check_world

    check_world(world_name)
    cfg_path = run_dir / "config.json"
    if not cfg_path.is_file():
        raise FileNotFoundError(f"{cfg_path} not found: RUN_DIR must be the output directory of python -m active.run")
    cfg = json.loads(cfg_path.read_text())
    settings = read_settings(cfg, method="all")
    exp, world, planner_cfg = settings.exp, settings.world, settings.planner
    if steps < 1 or not lr > 0:
        raise ValueError(f"--steps {steps} / --lr {lr}: allowed steps >= 1 and lr > 0")
    mde, ckpt = None, None
    if use_mde:
        method = method or exp.methods[0]
        if method not in exp.methods:
            raise ValueError(f"--method {method!r}: this run has {list(exp.methods)}")
        ckpt = _last_checkpoint(run_dir / method)
        if ckpt is None:
            raise FileNotFoundError(f"no MDE checkpoint (mde_iter*.pt) in {run_dir / method}")
        mde = mde_pkg.load(ckpt)
    dyn = planning_dynamics(settings.dynamics, world, exp, progress)
    seed = int(cfg["seed"])
    n = n_problems or exp.test_problems
    problems = sample_problems(world, n, derive_seed(seed, "test"), world="target")
    planner = Planner(dyn, mde, planner_cfg)
    t0 = time.perf_counter()
    plans = []
    for k, prob in enumerate(problems):
        r = planner.plan(
            prob.start,
            prob.goal,
            beta=exp.beta_test,
            d_max=exp.d_max,
            seed=derive_seed(seed, "test-plan", "refine-check", k),
        )
        plans.append(r.trajectory if r.found else None)
    t_plan = time.perf_counter() - t0
    idx = [k for k, p in enumerate(plans) if p is not None]
    out = {
        "run_dir": str(run_dir),
        "mde": str(ckpt) if ckpt else None,
        "world": world_name,
        "problems": n,
        "found": len(idx),
        "steps": steps,
        "lr": lr,
        "plan_seconds": t_plan,
    }
    if not idx:
        out.update(success_unrefined=0.0, success_refined=0.0)
        return out
    found = [plans[k] for k in idx]
    goals = [problems[k].goal for k in idx]
    ref = refine_plans(world, found, goals, steps=steps, lr=lr, progress=progress)
    from sim.execute import PouringExecutor

    ex = PouringExecutor(world)
    starts = np.array([problems[k].start[:3] for k in idx])
    jit = np.array([problems[k].plant_jitter for k in idx])
    if world_name == "source":
        jit[:] = 0.0
    # two runs with the same environment slots: each slot samples the same initial particles, so the
    # comparison is paired (the particle jitter alone moves a partial pour by a few percent)
    before = ex.run(world_name, starts, [p.actions for p in found], plant_jitter=jit, goals=goals)
    after = ex.run(world_name, starts, ref.actions, plant_jitter=jit, goals=goals)
    ex.close()
    rows = []
    for j, k in enumerate(idx):
        rows.append(
            {
                "problem": k,
                "goal": goals[j],
                "refined": bool(ref.refined[j]),
                "v_tgt_unrefined": float(before[j].states[-1, 4]),
                "v_tgt_refined": float(after[j].states[-1, 4]),
                "spill_unrefined": before[j].final_spill,
                "spill_refined": after[j].final_spill,
                "reached_unrefined": bool(before[j].goal_reached),
                "reached_refined": bool(after[j].goal_reached),
                "skipped": ref.skipped.get(j, ""),
            }
        )
    out.update(
        success_unrefined=sum(r["reached_unrefined"] for r in rows) / n,
        success_refined=sum(r["reached_refined"] for r in rows) / n,
        mean_abs_goal_error_unrefined=float(np.mean([abs(r["v_tgt_unrefined"] - r["goal"]) for r in rows])),
        mean_abs_goal_error_refined=float(np.mean([abs(r["v_tgt_refined"] - r["goal"]) for r in rows])),
        refined_pours=int(ref.refined.sum()),
        refine_seconds=ref.wall_seconds,
        sim_loss_before=np.nanmean(ref.loss_before).item() if len(ref.loss_before) else None,
        sim_loss_after=np.nanmean(ref.loss_after).item() if len(ref.loss_after) else None,
        params_before=ref.params_before.tolist(),
        params_after=ref.params_after.tolist(),
        plans=rows,
    )
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.refine_check",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--method", default=None, help="whose final MDE to plan with (default: the run's first method)")
    ap.add_argument("--no-mde", action="store_true", help="plan with the dynamics model alone (no precondition)")
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--lr", type=float, default=0.05, help="Adam step, in fractions of each parameter's range")
    ap.add_argument("--world", default="target", help="world the plans are executed in: source | target")
    ap.add_argument("--problems", type=int, default=None, help="number of test problems (default: the run's)")
    ap.add_argument("--out", type=Path, default=None, help="JSON file (default: RUN_DIR/refine_check.json)")
    args = ap.parse_args(argv)
    res = run_check(args.run_dir, args.method, args.steps, args.lr, args.world, args.problems, not args.no_mde)
    n = res["problems"]
    print(f"{n} test problems ({args.world} world), plans found {res['found']}")
    if res["found"]:
        print(f"  {'':22s} {'unrefined':>10s} {'refined':>10s}")
        print(f"  {'success rate':22s} {res['success_unrefined']:10.2f} {res['success_refined']:10.2f}")
        print(
            f"  {'mean |v_tgt - goal|':22s} {res['mean_abs_goal_error_unrefined']:10.3f} "
            f"{res['mean_abs_goal_error_refined']:10.3f}"
        )
        print(
            f"  refined {res['refined_pours']} pours in {res['refine_seconds']:.0f} s; "
            f"simulator loss {res['sim_loss_before']:.4f} -> {res['sim_loss_after']:.4f}"
        )
    path = args.out or args.run_dir / "refine_check.json"
    safeio.write_json(path, res, indent=1, default=float)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
