"""One large environment on all CPU threads: the split substep against the one-task path, same process.

    python -m benchmarks.sim_split [--dx 0.01 0.005] [--substeps 600 80] [--rounds 3] [--out F.json]

Scene: the peer benchmark's 3D dam break (``benchmarks/peers/dambreak_common.py``: 16,000 particles at
dx = 10 mm, 128,000 at 5 mm), B = 1. ``MPMSolver.step`` runs it in one task per environment (one thread)
when the scene holds at most ``sim.mpm._SPLIT_ENV_PARTICLES`` particles and split over the threads
(``_substep_split``) above; this benchmark forces each path on the same scene, alternating round by round
(each round continues the same simulation in both), checks that both give the same bits, and prints
particle-substeps/s and the ratio (best round against best round, and per round).
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

import sim.mpm as mpm  # noqa: E402
from sim.config import SimConfig  # noqa: E402
from sim.scene import EnvSpec, WaterBlock  # noqa: E402

PATHS = {"one_task": 10**12, "split": 0}  # the _SPLIT_ENV_PARTICLES that forces each path


def run_scene(dx: float, substeps: int, rounds: int) -> dict:
    """Time both paths on one dam-break scene at spacing ``dx``; returns a row of the table."""
    lo, hi = C.column_box(dx)
    cfg = SimConfig(dim=3, domain=C.domain_for(dx), dx=dx, dt=C.dt_for(dx), rho=C.RHO, sound_speed=C.SOUND_SPEED,
                    gravity=C.G, friction=0.0, ppc=C.PPC_1D**3, n_envs=1, max_particles=C.expected_particles(dx),
                    wall_cells=C.WALL_CELLS, jitter=0.0)
    solvers, seconds = {}, {k: [] for k in PATHS}
    default = mpm._SPLIT_ENV_PARTICLES
    try:
        for name, threshold in PATHS.items():
            mpm._SPLIT_ENV_PARTICLES = threshold
            s = mpm.MPMSolver(cfg)
            s.reset([EnvSpec(water=[WaterBlock(lo, hi)])])
            s.step(1)  # compile
            s.sync()
            s.reset([EnvSpec(water=[WaterBlock(lo, hi)])])
            solvers[name] = s
        for _ in range(rounds):
            for name, threshold in PATHS.items():
                mpm._SPLIT_ENV_PARTICLES = threshold
                t0 = time.perf_counter()
                solvers[name].step(substeps)
                solvers[name].sync()
                seconds[name].append(time.perf_counter() - t0)
        n = int(solvers["one_task"].particle_counts()[0])
        same = all(np.array_equal(getattr(solvers["one_task"], f)(0), getattr(solvers["split"], f)(0))
                   for f in ("positions", "velocities"))
        threads = solvers["split"].threads
    finally:
        mpm._SPLIT_ENV_PARTICLES = default
        for s in solvers.values():
            s.close()
    rate = {k: n * substeps / min(v) for k, v in seconds.items()}
    return {"dx": dx, "particles": n, "substeps_per_round": substeps, "threads": threads, "seconds": seconds,
            "particle_substeps_per_s": rate, "ratio_best": rate["split"] / rate["one_task"],
            "ratio_per_round": [a / b for a, b in zip(seconds["one_task"], seconds["split"])],
            "bit_identical": bool(same),
            "default_path": "split" if n > default else "one_task"}


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
    print(f"{'dx':>6} {'particles':>9} {'one task':>10} {'split':>10} {'ratio':>6}  per round      same bits")
    for dx, n in zip(args.dx, args.substeps):
        r = run_scene(dx, n, args.rounds)
        rows.append(r)
        ps = r["particle_substeps_per_s"]
        print(f"{dx:6.3f} {r['particles']:9d} {ps['one_task']:10.3e} {ps['split']:10.3e} {r['ratio_best']:6.2f}  "
              f"{' '.join(f'{x:.2f}' for x in r['ratio_per_round']):14s} {r['bit_identical']}")
    res = {"benchmark": "one 3D dam-break environment (B = 1): split substep vs one task, particle-substeps/s",
           "command": "python -m benchmarks.sim_split " + " ".join(argv if argv is not None else sys.argv[1:]),
           "split_threshold_particles": mpm._SPLIT_ENV_PARTICLES, "rows": rows,
           "machine": {"cpu_count": os.cpu_count(), "loadavg": list(os.getloadavg()), "python": platform.python_version()}}
    if args.out:
        safeio.write_json(args.out, res)
    return res


if __name__ == "__main__":
    main()
