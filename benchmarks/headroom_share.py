"""How often the planner's candidates enter the region R where the model is wrong, per target world, before any run:
``python -m benchmarks.headroom_share [--worlds default headroom_rare headroom_common] [--leaf SPAN HEIGHT ...]
[--problems 24] [--out FILE] [overrides]``.

Why: whether an acquisition function can beat a random pick among the candidates depends on how many candidates
meet the model's error at all. Where almost every candidate does, random data teach the MDE as much as chosen ones;
where almost none does, a random pick rarely finds R and a good choice can (the headroom study, issue 61). This plans
the round-1 training candidates of the quick preset (the model alone: no MDE exists yet, and the plant does not
enter the model, so the candidates are the same in every world), executes every candidate in the source world and in
each target world, labels each transition with its deviation from the model's prediction and reports per world:

* ``enters_R``: the share of candidates with at least one transition whose deviation exceeds ``d_max`` (what the MDE
  must learn to refuse), and ``stuck``: the share the plant caught;
* ``bad_transitions``: the share of transitions over ``d_max``; ``goal_reached``: the share that reached the goal.

The source world's row is the model's error outside any plant (the part of R no plant variant moves). ``--leaf SPAN
HEIGHT`` (m, repeatable) adds a variant of the default world whose first leaf (the one over the target cup's mouth)
spans SPAN from the stem at HEIGHT above the floor; ``--leaf-alone SPAN HEIGHT`` the same leaf as the whole plant
(no other leaves, a stub of a stem), so that R is where that leaf is.
"""

from __future__ import annotations

import argparse
import copy
import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from benchmarks._cli import report

#: trajectories per target-world simulation call
BATCH = 32
#: m, the stem of a leaf-only plant (``--leaf-alone``): a stub on the floor, below every cup position
STUB = 0.02


def leaf_world(world: dict, span: float, height: float, alone: bool = False) -> dict:
    """``world`` (a plain world config) with its first leaf spanning ``span`` (m) from the stem at ``height`` (m);
    ``alone``: that leaf is the whole plant (the other leaves gone, the stem a stub of :data:`STUB` m), so that the
    leaf is the only place the plant can catch a cup."""
    w = copy.deepcopy(world)
    leaf = w["plant"]["leaves"][0]
    leaf["center"] = [span / 2, height]
    leaf["radii"] = [span / 2, leaf["radii"][1]]
    if alone:
        w["plant"]["leaves"] = [leaf]
        w["plant"]["stem_height"] = STUB
    return w


def candidates(cfg: dict, n_problems: int, seed: int) -> tuple[Any, list, list]:
    """The planning dynamics, the problems and their candidate trajectories of the first rounds (as ``active.loop``
    plans them in round 1: no MDE, the first beta of the schedule), ``n_problems`` problems in all."""
    from active.planner_setup import planning_dynamics
    from active.seeds import derive_seed
    from active.settings import read_settings
    from planner.pool import PlanPool, PlanRequest
    from sim.problems import sample_problems

    settings = read_settings(cfg, method="all")
    exp, world = settings.exp, settings.world
    dyn = planning_dynamics(settings.dynamics, world, exp)
    per = exp.trajectories_per_iteration
    problems, reqs = [], []
    for it in range(math.ceil(n_problems / per)):
        probs = sample_problems(world, per, derive_seed(seed, "train", it), world="target")
        for k, p in enumerate(probs[: n_problems - len(problems)]):
            problems.append(p)
            reqs.append(
                PlanRequest(
                    "candidates",
                    p.start,
                    p.goal,
                    n=exp.candidates,
                    beta=exp.beta(0),
                    d_max=exp.d_max,
                    seed=derive_seed(seed, "plan", it, k),
                )
            )
    with PlanPool(dyn, settings.planner, settings.workers) as pool:
        sets = pool.run(reqs, None, errors="record")
    return dyn, problems, [list(s.candidates) for s in sets]


def share_in_world(
    world_cfg: dict, which: str, dyn: Any, problems: list, cands: list, d_max: float, name: str = ""
) -> dict:
    """Execute every candidate in ``which`` world of ``world_cfg``; the shares of the module docstring."""
    from tqdm.auto import tqdm

    from active.labels import label_transitions, stack_steps
    from sim.execute import PouringExecutor
    from sim.world import WorldConfig

    world = WorldConfig.from_mapping(world_cfg)
    flat = [(p, np.asarray(c.actions)) for p, cs in zip(problems, cands) for c in cs]
    executor = PouringExecutor(world)
    t0, results = time.perf_counter(), []
    try:
        for i in tqdm(range(0, len(flat), BATCH), desc=name or which, unit="batch"):
            chunk = flat[i : i + BATCH]
            results += executor.run(
                which,
                np.array([p.start[:3] for p, _ in chunk]),
                [a for _, a in chunk],
                plant_jitter=np.array([p.plant_jitter for p, _ in chunk]),
                goals=[p.goal for p, _ in chunk],
            )
    finally:
        executor.close()
    worst, bad, n = [], 0, 0
    for r in results:
        s, a, s2 = stack_steps([r])
        y = label_transitions(dyn, s, a, s2, world.distance_weights) if len(s) else np.zeros(0)
        worst.append(float(np.max(y)) if len(y) else 0.0)
        bad, n = bad + int(np.sum(y > d_max)), n + len(y)
    m = max(len(results), 1)
    return {
        "candidates": len(results),
        "enters_R": sum(w > d_max for w in worst) / m,
        "stuck": sum(r.category == "stuck_in_plant" for r in results) / m,
        "bad_transitions": bad / max(n, 1),
        "goal_reached": sum(bool(r.goal_reached) for r in results) / m,
        "sim_seconds": time.perf_counter() - t0,
    }


def main(argv: Sequence[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--worlds", nargs="*", default=["default"], help="world config names (configs/world/)")
    ap.add_argument("--leaf", nargs=2, type=float, action="append", default=[], metavar=("SPAN", "HEIGHT"))
    ap.add_argument(
        "--leaf-alone",
        nargs=2,
        type=float,
        action="append",
        default=[],
        metavar=("SPAN", "HEIGHT"),
        help="as --leaf, the leaf the whole plant (no other leaves, a stub of a stem)",
    )
    ap.add_argument("--problems", type=int, default=24, help="training problems (x experiment.candidates each)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path)
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of the run config (default experiment: quick)")
    args = ap.parse_args(argv)
    if args.problems < 1:
        ap.error(f"--problems {args.problems}: allowed an integer >= 1")
    from active.run import compose_config

    cfg = compose_config(["progress=false", *args.overrides])
    worlds = {
        f"world={w}": compose_config(["progress=false", f"world={w}", *args.overrides])["world"] for w in args.worlds
    }
    worlds |= {f"leaf span {s:.3f} m at {h:.3f} m": leaf_world(cfg["world"], s, h) for s, h in args.leaf}
    worlds |= {f"leaf alone, {s:.3f} m at {h:.3f} m": leaf_world(cfg["world"], s, h, True) for s, h in args.leaf_alone}
    t0 = time.perf_counter()
    print(f"planning {args.problems} x {cfg['experiment']['candidates']} candidates ...", flush=True)
    dyn, problems, cands = candidates(cfg, args.problems, args.seed)
    plan_s = time.perf_counter() - t0
    d_max = float(cfg["experiment"]["d_max"])
    src = "source world (no plant)"
    rows = {src: share_in_world(cfg["world"], "source", dyn, problems, cands, d_max, src)}
    rows |= {name: share_in_world(w, "target", dyn, problems, cands, d_max, name) for name, w in worlds.items()}
    lines = [
        f"{args.problems} problems x {cfg['experiment']['candidates']} candidates (round 1 of the quick preset's "
        f"streams, seed {args.seed}; planned in {plan_s:.0f} s); d_max {d_max}",
        f"| {'world':38s} | candidates | enters R | stuck | bad transitions | goal reached |",
        f"|{'-' * 40}|-----------:|---------:|------:|----------------:|-------------:|",
    ]
    for name, r in rows.items():
        lines.append(
            f"| {name:38s} | {r['candidates']:10d} | {r['enters_R']:8.2f} | {r['stuck']:5.2f} "
            f"| {r['bad_transitions']:15.2f} | {r['goal_reached']:12.2f} |"
        )
    result = {"problems": args.problems, "seed": args.seed, "plan_seconds": plan_s, "worlds": rows}
    report("\n".join(lines), result, args.out)
    return result


if __name__ == "__main__":
    main()
