"""Genesis side of the peer benchmark: the 3D dam break of dambreak_common.py with Genesis's MPM
``Liquid`` material. Runs in the virtual environment that benchmarks/peers/genesis.sh makes under
.cache/peers/genesis-venv (Genesis pins its own Taichi fork, Quadrants, and is no project dependency).

    .cache/peers/genesis-venv/bin/python benchmarks/peers/dambreak_genesis.py --dx 0.01 --threads 2 --out OUT.json

Mapping of the scene onto Genesis (its up axis is z; ours is y):
  * MPMOptions(lower_bound=0, upper_bound=domain, grid_density=1/dx): Genesis puts its walls
    (CubeBoundary, free slip: the outgoing normal velocity is zeroed, restitution 0) 3 dx inside the
    bounds, as our tank walls are 3 cells thick. Its grid has one more node per axis (both corners).
  * particle_size = dx / 2 (Genesis's particle volume is particle_size^3, so 8 particles per cell
    carry the cell's mass, as ours), sampler "regular": the same lattice as our jitter = 0 sampling.
  * Liquid(rho=1000, lam=K): non-viscous liquid (mu = 0) with stress lam J (J - 1) I, whose bulk
    modulus at J = 1 is lam; K = rho c^2 = 1.44e5 Pa (c = 12 m/s), as ours. Genesis's default
    (E = 1e6, nu = 0.2) would be lam = 2.78e5 Pa, c = 16.7 m/s.
  * SimOptions(dt = 10 substep dt, substeps = 10): one scene.step() = 10 substeps, as one frame of ours.
  * Threads: Genesis runs Quadrants with cpu_max_num_threads = 1 on the CPU unless QD_NUM_THREADS is
    set (genesis/__init__.py); this script sets QD_NUM_THREADS (and torch's threads) to --threads.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import dambreak_common as C  # noqa: E402


def to_ours(p: np.ndarray) -> np.ndarray:
    """Genesis (x, y, z up) -> ours (x, y up, z)."""
    return p[..., [0, 2, 1]]


def to_genesis(v) -> tuple:
    return (v[0], v[2], v[1])


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dx", type=float, default=0.01, help="grid spacing (m)")
    ap.add_argument("--envs", type=int, default=1, help="B: scene.build(n_envs=B) (B = 1: n_envs=0, unbatched)")
    ap.add_argument("--arch", choices=("cpu", "gpu"), default="cpu")
    ap.add_argument("--threads", type=int, default=0, help="CPU threads (QD_NUM_THREADS); 0 = all cores")
    ap.add_argument("--steps", type=int, default=0, help="substeps to time (rounded up to whole frames); 0 = to T = 3")
    ap.add_argument(
        "--no-performance-mode",
        action="store_true",
        help="gs.init(performance_mode=False) (default True: static arrays, Genesis's fastest mode)",
    )
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)

    load_start = list(os.getloadavg())
    threads = args.threads or os.cpu_count()
    os.environ["QD_NUM_THREADS"] = str(threads)
    os.environ.setdefault("OMP_NUM_THREADS", str(threads))
    import torch

    torch.set_num_threads(threads)
    import genesis as gs
    import quadrants as qd

    perf = not args.no_performance_mode
    gs.init(
        backend=gs.cpu if args.arch == "cpu" else gs.gpu, precision="32", logging_level="warning", performance_mode=perf
    )

    dx, dt, B = args.dx, C.dt_for(args.dx), args.envs
    per_frame = C.SUBSTEPS_PER_FRAME
    lo, hi = C.column_box(dx)
    n_exp = C.expected_particles(dx)
    dom = C.domain_for(dx)
    t0 = time.perf_counter()
    scene = gs.Scene(
        sim_options=gs.options.SimOptions(dt=dt * per_frame, substeps=per_frame, gravity=(0.0, 0.0, -C.G)),
        mpm_options=gs.options.MPMOptions(
            lower_bound=(0.0, 0.0, 0.0), upper_bound=to_genesis(dom), grid_density=1.0 / dx, particle_size=dx / C.PPC_1D
        ),
        show_viewer=False,
    )
    material = gs.materials.MPM.Liquid(rho=C.RHO, lam=C.BULK, sampler="regular")
    water = scene.add_entity(
        material=material,
        morph=gs.morphs.Box(lower=to_genesis(lo), upper=to_genesis(hi)),
        surface=gs.surfaces.Default(vis_mode="particle"),
    )
    scene.build(n_envs=B if B > 1 else 0)
    build_s = time.perf_counter() - t0

    def positions0() -> np.ndarray:
        p = water.get_particles_pos()
        p = p.detach().cpu().numpy() if hasattr(p, "detach") else np.asarray(p)
        if p.ndim == 3:
            p = p[0]
        return to_ours(p)

    t0 = time.perf_counter()
    scene.step()  # compile
    qd.sync()
    scene.reset()
    compile_s = time.perf_counter() - t0
    p0 = positions0()
    n = int(water.n_particles)
    solver = scene.sim.mpm_solver

    n_frames = C.frames_to_end(dt) if args.steps <= 0 else int(math.ceil(args.steps / per_frame))
    samples = set(C.sample_frames(dt, n_frames))
    front = C.new_front_record()
    timer = C.Timer(qd.sync)
    C.add_front(front, 0, dt, p0, dx)
    for f in range(1, n_frames + 1):
        with timer:
            scene.step()
        if f in samples:
            C.add_front(front, f, dt, positions0(), dx)
    substeps = n_frames * per_frame
    pend = positions0()

    res = {
        "solver": "genesis",
        "dx": dx,
        "dt": dt,
        "envs": B,
        "arch": args.arch,
        "threads": threads,
        "particles": n,
        "particles_expected": n_exp,
        "substeps": substeps,
        "substeps_per_frame": per_frame,
        "seconds": timer.seconds,
        "compile_seconds": compile_s,
        "build_seconds": build_s,
        "particle_substeps_per_s": B * n * substeps / timer.seconds,
        "front": front,
        "nan": bool(not np.isfinite(pend).all()),
        "initial_span_m": [p0.min(0).tolist(), p0.max(0).tolist()],
        "genesis_version": gs.__version__,
        "quadrants_version": ".".join(map(str, qd.__version__)),
        "torch_version": torch.__version__,
        "performance_mode": perf,
        "genesis_settings": {
            "SimOptions": {"dt": dt * per_frame, "substeps": per_frame, "gravity": [0.0, 0.0, -C.G]},
            "MPMOptions": {
                "lower_bound": [0.0, 0.0, 0.0],
                "upper_bound": list(to_genesis(dom)),
                "grid_density": 1.0 / dx,
                "particle_size": dx / C.PPC_1D,
            },
            "grid_res": [int(v) for v in solver.grid_res],
            "substep_dt": float(solver.substep_dt),
            "boundary_lower": solver.boundary.lower.tolist(),
            "boundary_upper": solver.boundary.upper.tolist(),
            "Liquid": {
                "rho": material.rho,
                "lam": material.lam,
                "mu": material.mu,
                "viscous": material.viscous,
                "sampler": material.sampler,
            },
            "QD_NUM_THREADS": os.environ.get("QD_NUM_THREADS"),
        },
        "scene": C.scene_record(dx),
        "machine": C.machine_info(),
        "loadavg_start": load_start,
        "loadavg_end": list(os.getloadavg()),
        "model": "Genesis MPM (MLS-MPM, APIC) Liquid: Kirchhoff stress lam J (J - 1) I, mu = 0; free-slip cube "
        "boundary 3 dx inside the grid bounds",
    }
    C.write_json(args.out, res)
    print(
        f"genesis dx={dx:g} B={B} particles={n} substeps={substeps} {timer.seconds:.2f} s "
        f"{res['particle_substeps_per_s']:.3g} p-sub/s  Z_p99(T={front['T'][-1]:.2f})={front['Z_p99'][-1]:.2f}"
    )
    return res


if __name__ == "__main__":
    main()
