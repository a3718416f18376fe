"""Do the CPU and GPU backends give the same outcomes? Runs one fixed batch of target-world
trajectories (scripted reference pours plus seeded random action sequences) on each arch, each in
its own process (Taichi holds one arch per process), and compares the observed states.

The GPU scatters particles to the grid with float atomics, whose summation order varies, so
single trajectories are not bit-identical to the CPU's: a splash that lands on a rim edge can fall
either way. What must agree is the deterministic part (the cup's pose, fixed by the kinematic
schedule and contact with static geometry) exactly, and the water fractions statistically: the mean
absolute difference of the fractions over the batch and the share of trajectories whose category
matches.

    python -m benchmarks.check_arch --arch gpu --reference cpu [--n 32] [--out check_arch.json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

import safeio

#: tolerances of the comparison (see the module docstring for why fractions are compared as means)
POSE_TOL = 1e-4  # m / rad: poses come from the schedule, identical on both arches
MEAN_FRACTION_TOL = 0.03  # mean |difference| of v_ctrl and v_tgt over the batch
CATEGORY_AGREEMENT_MIN = 0.85


def run_suite(arch: str, n: int, seed: int = 0) -> dict:
    """Execute the fixed batch on ``arch`` and return final states, categories and timing."""
    from benchmarks.sim_execute import OTHER_POURS, REFERENCE_POUR
    from sim.engine.backend import init_taichi
    from sim.execute import PouringExecutor
    from sim.problems import sample_problems
    from sim.skills import random_actions
    from sim.world import WorldConfig

    used = init_taichi(arch)
    cfg = WorldConfig.load()
    rng = np.random.default_rng(seed)
    scripted = [REFERENCE_POUR] + OTHER_POURS
    probs = sample_problems(cfg, n, seed)
    starts = [[0.42, 0.20, 0.0]] * len(scripted) + [list(p.start[:3]) for p in probs]
    actions = [a for _, a in scripted] + [random_actions(cfg, 6, rng) for _ in probs]
    jitter = np.concatenate([np.zeros((len(scripted), 3)), np.array([p.plant_jitter for p in probs])])
    ex = PouringExecutor(cfg, arch=arch)
    ex.solver(len(actions))
    t0 = time.perf_counter()
    res = ex.run("target", np.array(starts), actions, plant_jitter=jitter)
    wall = time.perf_counter() - t0
    ex.close()
    return {
        "arch": arch,
        "backend": used,
        "n": len(actions),
        "wall_seconds": wall,
        "final_states": [r.states[-1].tolist() for r in res],
        "categories": [r.category for r in res],
        "executed": [len(r.steps) for r in res],
        "unstable": [r.unstable for r in res],
    }


def compare(a: dict, b: dict) -> dict:
    """Differences between two suites run on different arches."""
    sa, sb = np.array(a["final_states"]), np.array(b["final_states"])
    pose = np.abs(sa[:, :3] - sb[:, :3]).max(axis=1)
    frac = np.abs(sa[:, 3:] - sb[:, 3:])
    cats = np.array(a["categories"]) == np.array(b["categories"])
    out = {
        "n": len(sa),
        "max_pose_difference": float(pose.max()),
        "mean_fraction_difference": float(frac.mean()),
        "max_fraction_difference": float(frac.max()),
        "fraction_difference_p90": float(np.quantile(frac, 0.9)),
        "category_agreement": float(cats.mean()),
        "executed_agreement": float(np.mean(np.array(a["executed"]) == np.array(b["executed"]))),
        "unstable": {a["arch"]: int(sum(a["unstable"])), b["arch"]: int(sum(b["unstable"]))},
        "wall_seconds": {a["arch"]: a["wall_seconds"], b["arch"]: b["wall_seconds"]},
        "tolerances": {
            "pose": POSE_TOL,
            "mean_fraction": MEAN_FRACTION_TOL,
            "category_agreement_min": CATEGORY_AGREEMENT_MIN,
        },
    }
    out["passed"] = bool(
        out["max_pose_difference"] <= POSE_TOL
        and out["mean_fraction_difference"] <= MEAN_FRACTION_TOL
        and out["category_agreement"] >= CATEGORY_AGREEMENT_MIN
        and not any(out["unstable"].values())
    )
    return out


def _run_in_subprocess(arch: str, n: int, seed: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, f"{arch}.json")
        cmd = [
            sys.executable,
            "-m",
            "benchmarks.check_arch",
            "--run-one",
            arch,
            "--n",
            str(n),
            "--seed",
            str(seed),
            "--out",
            path,
        ]
        subprocess.run(cmd, check=True)
        with open(path) as f:
            return json.load(f)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.check_arch",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--arch", default="gpu", help="arch under test (cpu | gpu | auto)")
    ap.add_argument("--reference", default="cpu", help="arch it is compared with")
    ap.add_argument("--n", type=int, default=32, help="random trajectories besides the scripted pours")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="check_arch.json")
    ap.add_argument("--run-one", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.n < 1:
        ap.error(f"--n = {args.n}: allowed an integer >= 1")
    if args.run_one:
        result = run_suite(args.run_one, args.n, args.seed)
    else:
        runs = {arch: _run_in_subprocess(arch, args.n, args.seed) for arch in (args.reference, args.arch)}
        cmp = compare(runs[args.reference], runs[args.arch])
        result = {"comparison": cmp, "runs": runs}
        print(f"{cmp['n']} target-world trajectories, {args.arch} vs {args.reference}:")
        for k in (
            "max_pose_difference",
            "mean_fraction_difference",
            "fraction_difference_p90",
            "max_fraction_difference",
            "category_agreement",
            "executed_agreement",
        ):
            print(f"  {k:26s} {cmp[k]:.4g}")
        print(f"  unstable                   {cmp['unstable']}")
        print("  wall seconds               " + ", ".join(f"{k} {v:.1f}" for k, v in cmp["wall_seconds"].items()))
        print(f"  {'PASSED' if cmp['passed'] else 'FAILED'} (tolerances {cmp['tolerances']})")
    safeio.write_json(args.out, result)
    if not args.run_one:
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
