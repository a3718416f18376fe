"""One large 3D environment on the CPU: the solver's paths on the same scene, same process.

    python -m benchmarks.sim_split [--dx 0.01 0.005] [--substeps 600 80] [--rounds 3] [--out F.json]

Scene: the peer benchmark's 3D dam break (``benchmarks/peers/dambreak_common.py``: 16,000 particles at
dx = 10 mm, 128,000 at 5 mm), B = 1. ``MPMSolver.step`` runs it in one task per environment (one thread)
when the scene holds at most ``sim.engine.mpm._SPLIT_ENV_PARTICLES`` particles and split over the threads
(``_substep_split``) above. Three paths, alternating round by round (each round continues the same
simulation in each): ``one_task`` and ``split`` (both with the factored 3D transfers of
``sim.engine.mpm._FACTORED_TRANSFERS``; they must give the same bits, which is checked), and ``direct``, the one-task
path with the direct transfers (the form 2D keeps; the same equations rounded otherwise: the
reference for the factored form's speed; its state drifts from the others' as any rounding change does in a
free-surface flow, reported as the largest position difference). Prints particle-substeps/s and the ratios
(best round against best round, and per round).
"""

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

import safeio

sys.path.insert(0, str(Path(__file__).resolve().parent / "peers"))
import dambreak_common as C  # noqa: E402  (tooling: the peer benchmark's scene, one definition)

import sim.engine.mpm as mpm  # noqa: E402
from sim.engine.config import SimConfig  # noqa: E402
from sim.engine.scene import EnvSpec, WaterBlock  # noqa: E402

#: each path's (_SPLIT_ENV_PARTICLES that forces it, _FACTORED_TRANSFERS it compiles with)
PATHS = {"one_task": (10**12, (3,)), "split": (0, (3,)), "direct": (10**12, ())}


def run_scene(dx: float, substeps: int, rounds: int) -> dict:
    """Time both paths on one dam-break scene at spacing ``dx``; returns a row of the table."""
    lo, hi = C.column_box(dx)
    cfg = SimConfig(
        dim=3,
        domain=C.domain_for(dx),
        dx=dx,
        dt=C.dt_for(dx),
        rho=C.RHO,
        sound_speed=C.SOUND_SPEED,
        gravity=C.G,
        friction=0.0,
        ppc=C.PPC_1D**3,
        n_envs=1,
        max_particles=C.expected_particles(dx),
        wall_cells=C.WALL_CELLS,
        jitter=0.0,
    )
    solvers, seconds = {}, {k: [] for k in PATHS}
    default, factored = mpm._SPLIT_ENV_PARTICLES, mpm._FACTORED_TRANSFERS
    try:
        for name, (threshold, dims) in PATHS.items():
            mpm._SPLIT_ENV_PARTICLES, mpm._FACTORED_TRANSFERS = threshold, dims  # read when the kernels compile
            s = mpm.MPMSolver(cfg)
            s.reset([EnvSpec(water=[WaterBlock(lo, hi)])])
            s.step(1)  # compile
            s.sync()
            s.reset([EnvSpec(water=[WaterBlock(lo, hi)])])
            solvers[name] = s
        for _ in range(rounds):
            for name, (threshold, _dims) in PATHS.items():
                mpm._SPLIT_ENV_PARTICLES = threshold
                t0 = time.perf_counter()
                solvers[name].step(substeps)
                solvers[name].sync()
                seconds[name].append(time.perf_counter() - t0)
        n = int(solvers["one_task"].particle_counts()[0])
        same = all(
            np.array_equal(getattr(solvers["one_task"], f)(0), getattr(solvers["split"], f)(0))
            for f in ("positions", "velocities")
        )
        drift = float(np.abs(solvers["one_task"].positions(0) - solvers["direct"].positions(0)).max())
        threads = solvers["split"].threads
    finally:
        mpm._SPLIT_ENV_PARTICLES, mpm._FACTORED_TRANSFERS = default, factored
        for s in solvers.values():
            s.close()
    rate = {k: n * substeps / min(v) for k, v in seconds.items()}
    return {
        "dx": dx,
        "particles": n,
        "substeps_per_round": substeps,
        "threads": threads,
        "seconds": seconds,
        "particle_substeps_per_s": rate,
        "ratio_best": rate["split"] / rate["one_task"],
        "ratio_per_round": [a / b for a, b in zip(seconds["one_task"], seconds["split"])],
        "factored_over_direct_best": rate["one_task"] / rate["direct"],
        "factored_over_direct_per_round": [a / b for a, b in zip(seconds["direct"], seconds["one_task"])],
        "bit_identical": bool(same),
        "direct_max_position_difference_m": drift,
        "default_path": "split" if n > default else "one_task",
    }


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dx", type=float, nargs="+", default=[0.01, 0.005])
    ap.add_argument("--substeps", type=int, nargs="+", default=[600, 80], help="per round, one per --dx")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    if len(args.substeps) != len(args.dx):
        ap.error(f"--substeps: give one count per --dx ({len(args.dx)}), got {len(args.substeps)}")
    rows = []
    print(
        f"{'dx':>6} {'particles':>9} {'direct':>10} {'one task':>10} {'split':>10} {'factored':>8}  per round"
        f"       {'split':>5}  per round       same bits  direct drift"
    )
    for dx, n in zip(args.dx, args.substeps):
        r = run_scene(dx, n, args.rounds)
        rows.append(r)
        ps = r["particle_substeps_per_s"]
        print(
            f"{dx:6.3f} {r['particles']:9d} {ps['direct']:10.3e} {ps['one_task']:10.3e} {ps['split']:10.3e} "
            f"{r['factored_over_direct_best']:8.2f}  {' '.join(f'{x:.2f}' for x in r['factored_over_direct_per_round']):14s} "  # noqa: E501 (a table row's format reads best on one line)
            f"{r['ratio_best']:5.2f}  {' '.join(f'{x:.2f}' for x in r['ratio_per_round']):14s} "
            f"{str(r['bit_identical']):9s}  {r['direct_max_position_difference_m'] * 1e3:.1f} mm"
        )
    res = {
        "benchmark": "one 3D dam-break environment (B = 1): the direct transfers (one task), the factored ones "
        "(one task, split), particle-substeps/s; factored = one task / direct, split = split / one task",
        "command": "python -m benchmarks.sim_split " + " ".join(argv if argv is not None else sys.argv[1:]),
        "split_threshold_particles": mpm._SPLIT_ENV_PARTICLES,
        "rows": rows,
        "machine": {"cpu_count": os.cpu_count(), "loadavg": list(os.getloadavg()), "python": platform.python_version()},
    }
    if args.out:
        safeio.write_json(args.out, res)
    return res


if __name__ == "__main__":
    main()
