"""Where a production substep spends its time, per stage (Taichi's kernel profiler).

    python -m benchmarks.sim_profile [--envs 32] [--substeps 400] [--world default] [--out sim_profile.json]

The per-stage table times the staged substep (``MPMSolver.step(staged=True)``: one offloaded loop per
stage, the same results); the production path's wall time (on the CPU one task runs whole substeps of one
environment, so no per-stage split exists there) is printed beneath it.

Scene: the default world's target-world scene (controlled cup full of water, target cup, plant) in
every environment, the cup moving and tilting (colliders with velocity, as in a pour). Each top-level
loop of ``MPMSolver._substep`` is one offloaded task that Taichi times separately; the table gives
ms per substep and the share of each stage. Run it alone: timings on a busy machine are not comparable.
"""

from __future__ import annotations

import argparse
import platform
import re
import time
from typing import Sequence

import numpy as np

import safeio

#: stages of ``MPMSolver._substep`` in loop order (CPU: one task per environment runs its whole grid phase)
STAGES_SERIAL = (
    "per env: clear grid, move bodies, particle to grid, grid update",
    "grid to particle (+ particle collider projection, J)",
)
STAGES_PARALLEL = (
    "clear grid",
    "move bodies",
    "particle to grid",
    "grid update (gravity, collider BC)",
    "grid to particle (+ particle collider projection, J)",
)


def profile(world_name: str = "default", envs: int = 32, substeps: int = 400, arch: str = "cpu") -> dict:
    """Per-stage kernel time of ``substeps`` substeps of ``envs`` environments (after a warm-up)."""
    import taichi as ti
    from taichi.profiler.kernel_profiler import get_default_kernel_profiler

    from active.run import compose_config
    from sim.engine.backend import init_taichi
    from sim.engine.mpm import MPMSolver
    from sim.world import WorldConfig

    init_taichi(arch, kernel_profiler=True)
    world = WorldConfig.from_mapping(compose_config([f"world={world_name}"])["world"])
    solver = MPMSolver(world.sim_config(envs))
    solver.reset([world.scene("target", (0.40 + 0.002 * (b % 5), 0.20, 0.0)) for b in range(envs)])
    solver.set_body_velocity(0, np.tile([[-0.1, 0.0]], (envs, 1)), np.full(envs, 0.8))
    per_tick = int(round(world.control_dt / solver.cfg.dt))  # substeps per control tick: one launch in sim.execute
    solver.step(50, staged=True)
    solver.step(per_tick)  # compile the production path too
    ti.sync()
    ti.profiler.clear_kernel_profiler_info()
    t0 = time.perf_counter()
    solver.step(substeps, staged=True)
    ti.sync()
    wall = time.perf_counter() - t0
    prof = get_default_kernel_profiler()
    prof._update_records()  # Taichi's own record list (no public accessor in 1.7)
    per_task: dict[int, float] = {}
    for rec in prof._traced_records:
        m = re.search(r"_substep_c\d+_\d+_kernel_(\d+)_", rec.name)
        if m:
            per_task[int(m.group(1))] = per_task.get(int(m.group(1)), 0.0) + rec.kernel_time
    names = STAGES_SERIAL if solver.serial_p2g else STAGES_PARALLEL
    n_particles = int(solver.particle_counts().sum())
    # the production path: what sim.execute runs, one launch per control tick
    ticks = -(-substeps // per_tick)
    t0 = time.perf_counter()
    for _ in range(ticks):
        solver.step(per_tick)
    ti.sync()
    production = (time.perf_counter() - t0) / (per_tick * ticks)
    solver.close()
    total = sum(per_task.values())
    rows = [
        {
            "stage": names[i] if i < len(names) else f"task {i}",
            "ms_per_substep": per_task[i] / substeps,
            "share": per_task[i] / total,
        }
        for i in sorted(per_task)
    ]
    return {
        "world": world_name,
        "envs": envs,
        "particles": n_particles,
        "substeps": substeps,
        "arch": arch,
        "stages": rows,
        "kernel_ms_per_substep": total / substeps,
        "wall_ms_per_substep": 1e3 * wall / substeps,
        "particle_substeps_per_s": n_particles * substeps / wall,
        "production_wall_ms_per_substep": 1e3 * production,
        "production_particle_substeps_per_s": n_particles / production,
        "machine": platform.machine(),
        "processor": platform.processor() or platform.machine(),
    }


def table(result: dict) -> str:
    lines = [
        f"{result['world']} world, B = {result['envs']}, {result['particles']} particles, {result['arch']}:",
        f"{'stage':55s} {'ms/substep':>10s} {'share':>6s}",
    ]
    for r in result["stages"]:
        lines.append(f"{r['stage']:55s} {r['ms_per_substep']:10.3f} {100 * r['share']:5.1f}%")
    lines.append(f"{'kernels, total':55s} {result['kernel_ms_per_substep']:10.3f}")
    lines.append(
        f"wall {result['wall_ms_per_substep']:.3f} ms/substep, "
        f"{result['particle_substeps_per_s'] / 1e6:.2f} M particle-substeps/s (staged: one launch per substep)"
    )
    lines.append(
        f"production path (sim.execute: one launch per control tick; CPU: whole substeps per environment) "
        f"{result['production_wall_ms_per_substep']:.3f} ms/substep, "
        f"{result['production_particle_substeps_per_s'] / 1e6:.2f} M particle-substeps/s"
    )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.sim_profile",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--envs", type=int, default=32)
    ap.add_argument("--substeps", type=int, default=400)
    ap.add_argument("--world", default="default", help="a config of configs/world (default, medium, fine)")
    ap.add_argument("--arch", default="cpu", choices=("cpu", "gpu"))
    ap.add_argument("--out", default=None, help="JSON file to write")
    args = ap.parse_args(argv)
    if args.envs < 1 or args.substeps < 1:
        ap.error(f"--envs {args.envs} / --substeps {args.substeps}: allowed >= 1")
    result = profile(args.world, args.envs, args.substeps, args.arch)
    print(table(result))
    if args.out:
        safeio.write_json(args.out, result, indent=1)
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
