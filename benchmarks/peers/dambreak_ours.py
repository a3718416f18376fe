"""Our side of the Genesis peer benchmark: the 3D dam break of dambreak_common.py in sim.engine.mpm.MPMSolver.

    python benchmarks/peers/dambreak_ours.py --dx 0.01 --envs 1 --threads 2 --out OUT.json

Compiles (one substep, then a reset) outside the timed region, then simulates the dam break to
T = t sqrt(2g/a) = 3 (or ``--steps`` substeps) in frames of 10 substeps, timing only the stepping;
the surge front of environment 0 is read between frames at the sample times, outside the timer.
Runs in the project's own Python (``pip install -e .``).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import dambreak_common as C  # noqa: E402


def _git_state() -> dict:
    """Commit of the solver's code and whether sim/ had uncommitted edits when it ran."""
    import subprocess

    def git(*a):
        try:
            return subprocess.run(["git", *a], cwd=C.REPO, capture_output=True, text=True, timeout=10).stdout.rstrip()
        except (OSError, subprocess.SubprocessError):
            return None

    import sim

    return {
        "commit": git("rev-parse", "HEAD"),
        "sim_dirty_files": (git("status", "--porcelain", "--", "sim") or "").split("\n"),
        "sim_path": str(Path(sim.__file__).parent),
    }


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dx", type=float, default=0.01, help="grid spacing (m)")
    ap.add_argument("--envs", type=int, default=1, help="B, independent copies of the scene")
    ap.add_argument("--arch", choices=("cpu", "gpu"), default="cpu")
    ap.add_argument("--threads", type=int, default=0, help="CPU threads (Taichi cpu_max_num_threads); 0 = all")
    ap.add_argument("--steps", type=int, default=0, help="substeps to time (rounded up to whole frames); 0 = to T = 3")
    ap.add_argument(
        "--nondeterministic",
        action="store_true",
        help="SimConfig.deterministic = False (particle-parallel atomic P2G on the CPU too)",
    )
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)

    load_start = list(os.getloadavg())
    if args.threads > 0:
        # read by ti.init (Taichi's TI_<option> environment configuration) inside sim.engine.backend.init_taichi
        os.environ["TI_CPU_MAX_NUM_THREADS"] = str(args.threads)
    import taichi as ti

    from sim.engine.config import SimConfig
    from sim.engine.mpm import MPMSolver
    from sim.engine.scene import EnvSpec, WaterBlock

    dx, dt, B = args.dx, C.dt_for(args.dx), args.envs
    lo, hi = C.column_box(dx)
    n_exp = C.expected_particles(dx)
    cfg = SimConfig(
        dim=3,
        domain=C.domain_for(dx),
        dx=dx,
        dt=dt,
        rho=C.RHO,
        sound_speed=C.SOUND_SPEED,
        gravity=C.G,
        friction=0.0,
        ppc=C.PPC_1D**3,
        n_envs=B,
        max_particles=n_exp,
        wall_cells=C.WALL_CELLS,
        arch=args.arch,
        deterministic=not args.nondeterministic,
        jitter=0.0,
    )  # a regular lattice, the same positions as Genesis's "regular" sampler
    specs = [EnvSpec(water=[WaterBlock(lo, hi)]) for _ in range(B)]
    t0 = time.perf_counter()
    solver = MPMSolver(cfg)
    solver.reset(specs)
    solver.step(1)  # compile
    ti.sync()
    solver.reset(specs)
    compile_s = time.perf_counter() - t0
    counts = solver.particle_counts()
    n = int(counts[0])

    per_frame = C.SUBSTEPS_PER_FRAME
    n_frames = C.frames_to_end(dt) if args.steps <= 0 else int(math.ceil(args.steps / per_frame))
    samples = set(C.sample_frames(dt, n_frames))
    front = C.new_front_record()
    timer = C.Timer(ti.sync)
    C.add_front(front, 0, dt, solver.positions(0), dx)
    for f in range(1, n_frames + 1):
        with timer:
            solver.step(per_frame)
        if f in samples:
            C.add_front(front, f, dt, solver.positions(0), dx)
    substeps = n_frames * per_frame
    st = solver.stability()
    cfg_d = cfg.to_dict()
    solver.close()
    import taichi

    res = {
        "solver": "ours",
        "source": _git_state(),
        "dx": dx,
        "dt": dt,
        "envs": B,
        "arch": args.arch,
        "threads": args.threads or os.cpu_count(),
        "particles": n,
        "particles_expected": n_exp,
        "particles_per_env": [int(c) for c in counts],
        "substeps": substeps,
        "substeps_per_frame": per_frame,
        "seconds": timer.seconds,
        "compile_seconds": compile_s,
        "particle_substeps_per_s": B * n * substeps / timer.seconds,
        "front": front,
        "unstable": bool(st["unstable"].any()),
        "nan": bool(st["nan"].any()),
        "taichi_version": ".".join(map(str, taichi.__version__)),
        "config": cfg_d,
        "scene": C.scene_record(dx),
        "machine": C.machine_info(),
        "loadavg_start": load_start,
        "loadavg_end": list(os.getloadavg()),
        "model": "MLS-MPM (APIC), p = K (1 - J), K = rho c^2; tension on, volume correction on (SimConfig defaults); "
        "free-slip tank walls 3 cells thick",
    }
    C.write_json(args.out, res)
    print(
        f"ours  dx={dx:g} B={B} particles={n} substeps={substeps} {timer.seconds:.2f} s "
        f"{res['particle_substeps_per_s']:.3g} p-sub/s  Z_p99(T={front['T'][-1]:.2f})={front['Z_p99'][-1]:.2f}"
    )
    return res


if __name__ == "__main__":
    main()
