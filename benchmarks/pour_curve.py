"""A full cup's pour outcome against the tilt angle, simulated and as the learned model predicts it:
``python -m benchmarks.pour_curve [--positions X,Y ...] [--holds 0 0.5 1] [--out FILE] [overrides]``.

Why: plans of the model alone can miss the goal in the world the model was trained in (the ladder's
source rung) by more than a pour's scatter. This shows the map
the model has to learn where the planner uses it: for each start position and hold time, one pour
per angle on a grid over the steep part of the curve (source world, one batched simulation), the
fraction that ends in the target cup and the spill, next to the model's one-step prediction from
the same state and action. Prints a table and the mean absolute error per curve; writes JSON.

``--world target --jitters K``: the same pours in the target world, each under K plant poses drawn
as the problems draw them (seeded); the table gives the mean over the poses and the JSON each one.
That maps where a pour is safe whatever the plant's jitter (the precondition's job in the target
world) against where the outcome depends on it.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Sequence

import numpy as np

from benchmarks._cli import report


def _position(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected X,Y in metres, e.g. 0.36,0.20") from None
    return x, y


def plant_jitters(world, k: int, seed: int = 0) -> np.ndarray:
    """k plant-pose jitters (dx, dy, dtilt), drawn as the problems draw them
    (:func:`task.problems.draw_plant_jitter`)."""
    from task.problems import draw_plant_jitter

    rng = np.random.default_rng(seed)
    return np.array([draw_plant_jitter(world.plant, rng) for _ in range(k)])


def run(
    positions: Sequence[tuple[float, float]],
    holds: Sequence[float],
    thetas: np.ndarray,
    overrides: Sequence[str] = (),
    world_name: str = "source",
    jitters: int = 1,
) -> dict:
    import dynamics
    from active.run import compose_config
    from sim.execute import PouringExecutor
    from sim.skills import pour
    from sim.world import WorldConfig

    cfg = compose_config(list(overrides))
    world = WorldConfig.from_mapping(cfg["world"])
    model = dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False)
    jit = plant_jitters(world, jitters) if world_name == "target" else np.zeros((1, 3))
    starts, acts, keys, jits = [], [], [], []
    for x, y in positions:
        for hold in holds:
            for theta in thetas:
                for j in jit:
                    starts.append((x, y))
                    acts.append([pour(float(theta), float(hold))])
                    keys.append((x, y, float(hold)))
                    jits.append(j)
    ex = PouringExecutor(world)
    try:
        blocked = ex.start_obstacles(world_name, np.array(starts), np.array(jits))  # e.g. a leaf where the cup would be
        run_idx = [i for i, b in enumerate(blocked) if b is None]
        ran = (
            ex.run(
                world_name,
                np.array(starts)[run_idx],
                [acts[i] for i in run_idx],
                plant_jitter=np.array(jits)[run_idx],
                goals=[0.5] * len(run_idx),
            )
            if run_idx
            else []
        )
    finally:
        ex.close()
    res: list = [None] * len(acts)
    for i, r in zip(run_idx, ran):
        res[i] = r
    nj = len(jit)
    s = np.array([[x, y, 0.0, 1.0, 0.0] for x, y in starts])
    a = np.array([act[0] for act in acts])
    pred = model.predict_np(s, a)
    curves = []
    for key in dict.fromkeys(keys):
        idx = np.array([i for i, k in enumerate(keys) if k == key]).reshape(len(thetas), nj)  # angle x plant pose
        nan = float("nan")  # a plant pose that leaves no room for the cup here: not run
        vt = np.array([[nan if res[i] is None else res[i].states[-1, 4] for i in row] for row in idx])
        spill = np.array([[nan if res[i] is None else res[i].final_spill for i in row] for row in idx])
        stuck = np.array([[res[i] is not None and bool(res[i].stuck) for i in row] for row in idx])
        ran_here = ~np.isnan(vt[0])
        if not ran_here.any():
            curves.append({"x": key[0], "y": key[1], "hold": key[2], "blocked_by": blocked[idx[0, 0]]})
            continue
        sim_vt, model_vt = vt[:, ran_here].mean(1), pred[idx[:, 0], 4]
        curve = {
            "x": key[0],
            "y": key[1],
            "hold": key[2],
            "sim_v_tgt": sim_vt.tolist(),
            "sim_spill": spill[:, ran_here].mean(1).tolist(),
            "model_v_tgt": model_vt.tolist(),
            "mean_abs_error": float(np.abs(vt[:, ran_here] - model_vt[:, None]).mean()),
            "largest_step": float(np.abs(np.diff(sim_vt)).max()),
        }
        if nj > 1:  # per plant pose, and the share of poses where the pour was clean (spill <= 2 %, not stuck);
            # a pose that blocks the start counts as not clean (the cup cannot pour from there)
            clean = (spill <= 0.02) & ~stuck & ~np.isnan(spill)
            curve.update(
                sim_v_tgt_per_jitter=vt.tolist(),
                sim_spill_per_jitter=spill.tolist(),
                stuck_per_jitter=stuck.tolist(),
                poses_run=int(ran_here.sum()),
                clean_share=clean.mean(1).tolist(),
            )
        curves.append(curve)
    return {
        "thetas": thetas.tolist(),
        "overrides": list(overrides),
        "world": world_name,
        "plant_jitters": jit.tolist(),
        "curves": curves,
    }


def format_table(r: dict) -> str:
    th = r["thetas"]
    lines = ["theta            " + " ".join(f"{t:5.2f}" for t in th)]
    for c in r["curves"]:
        if "blocked_by" in c:
            lines.append(
                f"({c['x']:.2f}, {c['y']:.2f}) hold {c['hold']:.1f}  not run: the cup overlaps the {c['blocked_by']}"
            )
            continue
        lines.append(
            f"({c['x']:.2f}, {c['y']:.2f}) hold {c['hold']:.1f}  mean abs error {c['mean_abs_error']:.3f}, "
            f"largest step between angles {c['largest_step']:.2f}"
        )
        lines.append("  simulated      " + " ".join(f"{v:5.2f}" for v in c["sim_v_tgt"]))
        lines.append("  model          " + " ".join(f"{v:5.2f}" for v in c["model_v_tgt"]))
        lines.append("  spill          " + " ".join(f"{v:5.2f}" for v in c["sim_spill"]))
        if "clean_share" in c:
            lines.append(
                f"  clean share ({c['poses_run']} of {len(r['plant_jitters'])} plant poses leave room to pour)"
            )
            lines.append("                 " + " ".join(f"{v:5.2f}" for v in c["clean_share"]))
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.pour_curve", description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--positions",
        type=_position,
        nargs="+",
        default=[(0.36, 0.20), (0.40, 0.16)],
        help="start positions X,Y (m) of the full, upright cup",
    )
    ap.add_argument("--holds", type=float, nargs="+", default=[0.0, 0.5, 1.0], help="hold times (s)")
    ap.add_argument("--theta-range", type=float, nargs=2, default=[1.1, 1.7], help="tilt angles from, to (rad)")
    ap.add_argument("--angles", type=int, default=16, help="angles on that range")
    ap.add_argument("--world", default="source", help="source | target (the plant, under --jitters poses)")
    ap.add_argument("--jitters", type=int, default=8, help="plant poses per pour in the target world")
    ap.add_argument("--out", type=Path, default=None, help="write the result as JSON here")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of the config (world, dynamics)")
    args = ap.parse_args(argv)
    if args.angles < 2:
        ap.error(f"--angles {args.angles}: allowed >= 2")
    if args.world not in ("source", "target"):
        ap.error(f"--world {args.world!r}: allowed source, target")
    if args.jitters < 1:
        ap.error(f"--jitters {args.jitters}: allowed >= 1")
    r = run(
        args.positions,
        args.holds,
        np.linspace(*args.theta_range, args.angles),
        args.overrides,
        world_name=args.world,
        jitters=args.jitters,
    )
    report(format_table(r), r, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
