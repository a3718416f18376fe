"""Wall time to execute a batch of target-world trajectories, with the share per stage, and a
resolution check of a reference pour.

    python -m benchmarks.sim_execute [--n 32] [--actions 6] [--out benchmarks/results/execute.json] [--resolution]
    python -m benchmarks.sim_execute --skip-batch --spread --spread-dx 0.01 0.005 0.0025 --arch gpu
"""

import argparse
import time

import numpy as np

import safeio
from sim.execute import PouringExecutor
from sim.problems import sample_problems
from sim.skills import move, pour, random_actions
from sim.world import WorldConfig


def bench_batch(
    cfg: WorldConfig, n: int, n_actions: int, seed: int = 0, arch: str | None = None, compare: bool = True
) -> dict:
    """Execute n random trajectories; with ``compare`` also the unfrozen path (every environment simulated
    to the end of the longest trajectory) on the same batch, in the same process, checking that the
    observations agree bit for bit, and the speed-up."""
    rng = np.random.default_rng(seed)
    probs = sample_problems(cfg, n, seed)
    acts = [random_actions(cfg, n_actions, rng) for _ in range(n)]
    ex = PouringExecutor(cfg, arch=arch)
    kw = dict(plant_jitter=np.array([p.plant_jitter for p in probs]), goals=[p.goal for p in probs])
    starts = np.array([p.start[:3] for p in probs])
    t0 = time.perf_counter()  # compile outside the timed region: a one-tick trajectory per environment
    ex.run("target", starts, [[pour(0.0, 0.0)] for _ in range(n)], **kw)
    warm_up = time.perf_counter() - t0
    runs = {}
    for freeze in (False, True) if compare else (True,):
        t0 = time.perf_counter()
        res = ex.run("target", starts, acts, freeze_done=freeze, progress=True, **kw)
        runs[freeze] = (res, time.perf_counter() - t0, dict(ex.last_timing))
    ex.close()
    res, wall, timing = runs[True]
    cats = {
        c: sum(r.category == c for r in res)
        for c in ("successful_pour", "unsuccessful_pour", "stuck_in_plant", "other")
    }
    shares = {k: timing[k] / timing["total"] for k in ("schedule", "simulate", "control", "state_queries", "frames")}
    out = {
        "n": n,
        "actions": n_actions,
        "wall_seconds": wall,
        "warm_up_seconds": warm_up,
        "timing": timing,
        "shares": shares,
        "trajectories_per_second": n / wall,
        "env_ticks_run_per_second": timing["env_ticks_run"] / wall,
        "categories": cats,
        "executed_actions": int(sum(len(r.steps) for r in res)),
        "env_ticks_run": timing["env_ticks_run"],
        "env_ticks": timing["env_ticks"],
    }
    if compare:
        old, old_wall, old_timing = runs[False]
        out["all_envs_to_the_end"] = {"wall_seconds": old_wall, "timing": old_timing}
        out["speedup"] = old_wall / wall
        out["identical"] = all(
            np.array_equal(a.states, b.states) and a.category == b.category for a, b in zip(old, res)
        )
    return out


#: reference pour: from below the canopy, tilt past horizontal (empties the cup into the target)
REFERENCE_POUR = ("reference theta=1.8 hold=1.0", [move(0.31, 0.14), pour(1.8, 1.0)])
#: partial pours, reported alongside: they leave water in the cup and are more resolution-sensitive
OTHER_POURS = [
    ("partial theta=1.3 hold=1.0", [move(0.31, 0.14), pour(1.3, 1.0)]),
    ("partial theta=1.5 hold=0.5", [move(0.31, 0.14), pour(1.5, 0.5)]),
    ("full theta=2.2 hold=1.0", [move(0.31, 0.14), pour(2.2, 1.0)]),
]


def at_resolution(cfg: WorldConfig, dx: float) -> WorldConfig:
    """The same world at grid spacing dx: time step and particle room scaled, tank walls kept in metres
    (so the floor, and every position measured from it, stays where it is)."""
    f = cfg.sim["dx"] / dx
    wall_m = cfg.sim_config(1).wall_cells * cfg.sim["dx"]
    sim = dict(
        cfg.sim,
        dx=dx,
        dt=cfg.sim["dt"] / f,
        max_particles=int(cfg.sim["max_particles"] * f * f),
        wall_cells=int(round(wall_m / dx)),
    )
    return WorldConfig.from_mapping(
        {
            **cfg.__dict__,
            "sim": sim,
            "controlled_cup": cfg.controlled_cup.__dict__,
            "target_cup": cfg.target_cup.__dict__,
        }
    )


def resolution_check(cfg: WorldConfig, world: str = "source", arch: str | None = None) -> dict:
    """Fraction poured into the target cup at dx and dx/2 for the reference and other pours."""
    scripts = [REFERENCE_POUR] + OTHER_POURS
    per_dx = {}
    for factor in (1, 2):
        dx = cfg.sim["dx"] / factor
        c = at_resolution(cfg, dx)
        ex = PouringExecutor(c, arch=arch)
        t0 = time.perf_counter()
        res = ex.run(world, np.array([[0.42, 0.20]] * len(scripts)), [a for _, a in scripts])
        ex.close()
        per_dx[dx] = {
            "wall_seconds": time.perf_counter() - t0,
            "pours": {
                name: {
                    "in_target": float(r.states[-1, 4]),
                    "left_in_cup": float(r.states[-1, 3]),
                    "spill": r.final_spill,
                }
                for (name, _), r in zip(scripts, res)
            },
        }
    (d1, a), (d2, b) = per_dx.items()
    diffs = {name: abs(a["pours"][name]["in_target"] - b["pours"][name]["in_target"]) for name, _ in scripts}
    return {
        "world": world,
        "dx": [d1, d2],
        "runs": {str(k): v for k, v in per_dx.items()},
        "difference_in_target": diffs,
        "reference": REFERENCE_POUR[0],
        "reference_difference": diffs[REFERENCE_POUR[0]],
        "target_max_difference": 0.05,
    }


def outcome_spread(
    cfg: WorldConfig, dxs=(0.01, 0.005), n: int = 32, thetas=(1.15, 1.25), seed: int = 7, arch: str | None = None
) -> list[dict]:
    """How much does the same pour's outcome vary? ``move(0.32, 0.20), pour(theta, 0.5)`` run (a) from
    one start in n environment slots (only the initial particle jitter differs) and (b) from n sampled
    problem starts (different approach histories; trajectories stuck on the way are dropped), per grid
    spacing. The tank walls keep their thickness in metres, so the geometry is the same at every dx."""
    rows = []
    for dx in dxs:
        c = at_resolution(cfg, dx)
        starts = np.array([p.start[:3] for p in sample_problems(c, n, seed)])
        ex = PouringExecutor(c, arch=arch)
        for th in thetas:
            acts = [[move(0.32, 0.20), pour(th, 0.5)]] * n
            same = ex.run("source", np.array([[0.42, 0.20, 0.0]] * n), acts)
            appr = [r for r in ex.run("source", starts, acts) if not r.stuck]
            a = np.array([r.states[-1, 4] for r in same])
            b = np.array([r.states[-1, 4] for r in appr])
            rows.append(
                {
                    "dx": dx,
                    "theta": th,
                    "slots_mean": float(a.mean()),
                    "slots_std": float(a.std()),
                    "approaches": len(b),
                    "approaches_mean": float(b.mean()),
                    "approaches_std": float(b.std()),
                }
            )
        ex.close()
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.sim_execute",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--actions", type=int, default=6)
    ap.add_argument("--out", default="bench_execute.json")
    ap.add_argument("--resolution", action="store_true", help="also run the resolution check")
    ap.add_argument("--skip-batch", action="store_true", help="only the resolution check")
    ap.add_argument("--no-compare", action="store_true", help="skip the unfrozen run of the batch")
    ap.add_argument("--arch", default=None, help="cpu | gpu | auto (default: the world config's)")
    ap.add_argument("--spread", action="store_true", help="also measure the outcome spread of one pour")
    ap.add_argument("--spread-dx", type=float, nargs="+", default=[0.01, 0.005])
    args = ap.parse_args(argv)
    cfg = WorldConfig.load()
    result = {}
    if not args.skip_batch:
        result["batch"] = row = bench_batch(cfg, args.n, args.actions, arch=args.arch, compare=not args.no_compare)
        print(
            f"{args.n} target-world trajectories x {args.actions} actions: {row['wall_seconds']:.1f} s wall "
            f"({row['timing']['sim_seconds']:.1f} s simulated, {row['timing']['substeps']} substeps of the batch; "
            f"{row['env_ticks_run']} of {row['env_ticks']} environment-ticks run, finished environments frozen); "
            f"{row['trajectories_per_second']:.2f} trajectories/s, warm-up (compile) {row['warm_up_seconds']:.1f} s"
        )
        if "speedup" in row:
            print(
                f"  every environment to the end (unfrozen): {row['all_envs_to_the_end']['wall_seconds']:.1f} s; "
                f"speed-up {row['speedup']:.2f}x; observations identical: {row['identical']}"
            )
        for k, v in row["shares"].items():
            print(f"  {k:14s} {100 * v:5.1f} %")
        print("  categories:", row["categories"])
    if args.resolution:
        result["resolution"] = res = resolution_check(cfg, arch=args.arch)
        d1, d2 = res["dx"]
        print(f"resolution check ({res['world']} world), fraction poured into the target cup (target |diff| <= 0.05):")
        print(f"  {'pour':30s} {f'dx={d1:g}':>10s} {f'dx={d2:g}':>10s} {'|diff|':>7s}")
        for name, diff in res["difference_in_target"].items():
            a = res["runs"][str(d1)]["pours"][name]["in_target"]
            b = res["runs"][str(d2)]["pours"][name]["in_target"]
            print(f"  {name:30s} {a:10.3f} {b:10.3f} {diff:7.3f}")
    if args.spread:
        result["spread"] = rows = outcome_spread(cfg, args.spread_dx, arch=args.arch)
        print("outcome spread of move(0.32, 0.20), pour(theta, 0.5): fraction into the target cup")
        print(
            f"  {'dx':>7s} {'theta':>6s} {'slots mean':>11s} {'std':>6s} {'approaches':>11s} {'mean':>6s} {'std':>6s}"
        )
        for r in rows:
            print(
                f"  {r['dx']:7.4f} {r['theta']:6.2f} {r['slots_mean']:11.3f} {r['slots_std']:6.3f} "
                f"{r['approaches']:11d} {r['approaches_mean']:6.3f} {r['approaches_std']:6.3f}"
            )
    safeio.write_json(args.out, result)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
