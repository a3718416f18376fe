"""Solver throughput against a bare reference MLS-MPM kernel, in the same process.

    python -m benchmarks.sim_solver [--out bench_sim.json] [--envs 1 8 32] [--seconds 0.3] [--scene pouring|world]

Scene ``pouring`` (the lighter one): a pouring-like world (a cup of water carried over
a target cup on the floor, i.e. moving colliders, SDF queries and projection all active; ppc 4, the
solver's plain defaults). Scene ``world``: the default world's target-world scene (its water model, full
cup, target cup and plant), the cup moving and tilting. Reference: Taichi's mpm88 water written out here
(APIC, J-based pressure, domain walls only, particle-parallel atomics) with the same particle count,
grid and number of environments B. Figure: particle-substeps per second = B * particles * substeps / s.
"""

import argparse
import os
import platform
import time

import numpy as np
import taichi as ti

import safeio
from sim.engine.backend import init_taichi
from sim.engine.config import SimConfig
from sim.engine.mpm import MPMSolver
from sim.engine.scene import Body, EnvSpec, WaterBlock, open_box


@ti.data_oriented
class ReferenceMPM88:
    """Batched mpm88 (Taichi's 88-line water), domain walls only: the speed of bare MLS-MPM."""

    def __init__(
        self,
        B: int,
        N: int,
        res: tuple[int, int],
        dx: float,
        dt: float,
        bulk: float,
        p_vol: float,
        rho: float,
        gravity: float,
        init_x: np.ndarray,
    ):
        self.B, self.N, self.res = B, N, res
        self.dx, self.dt, self.bulk, self.p_vol, self.p_mass, self.g = dx, dt, bulk, p_vol, rho * p_vol, gravity
        fb = ti.FieldsBuilder()
        self.x = ti.Vector.field(2, ti.f32)
        self.v = ti.Vector.field(2, ti.f32)
        self.C = ti.Matrix.field(2, 2, ti.f32)
        self.J = ti.field(ti.f32)
        fb.dense(ti.ij, (B, N)).place(self.x, self.v, self.C, self.J)
        self.grid_v = ti.Vector.field(2, ti.f32)
        self.grid_m = ti.field(ti.f32)
        fb.dense(ti.ijk, (B,) + res).place(self.grid_v, self.grid_m)
        self._tree = fb.finalize()
        ti.sync()  # materialise now: Taichi validates pending fields lazily, and a closed solver's would fail
        self.x.from_numpy(init_x.astype(np.float32))
        self.J.fill(1.0)

    @ti.kernel
    def substep(self):
        dx, dt = ti.static(self.dx, self.dt)
        for I in ti.grouped(self.grid_m):
            self.grid_v[I] = ti.Vector.zero(ti.f32, 2)
            self.grid_m[I] = 0.0
        for b, p in self.x:
            Xp = self.x[b, p] / dx
            base = ti.cast(Xp - 0.5, ti.i32)
            fx = Xp - base
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1) ** 2, 0.5 * (fx - 0.5) ** 2]
            stress = -dt * 4 * self.bulk * self.p_vol * (self.J[b, p] - 1) / dx**2
            affine = ti.Matrix([[stress, 0], [0, stress]]) + self.p_mass * self.C[b, p]
            for i, j in ti.static(ti.ndrange(3, 3)):
                offset = ti.Vector([i, j])
                dpos = (offset - fx) * dx
                weight = w[i][0] * w[j][1]
                self.grid_v[b, base + offset] += weight * (self.p_mass * self.v[b, p] + affine @ dpos)
                self.grid_m[b, base + offset] += weight * self.p_mass
        for b, i, j in self.grid_m:
            if self.grid_m[b, i, j] > 0:
                self.grid_v[b, i, j] /= self.grid_m[b, i, j]
            self.grid_v[b, i, j][1] -= dt * self.g
            if i < 3 and self.grid_v[b, i, j][0] < 0:
                self.grid_v[b, i, j][0] = 0
            if i > self.res[0] - 3 and self.grid_v[b, i, j][0] > 0:
                self.grid_v[b, i, j][0] = 0
            if j < 3 and self.grid_v[b, i, j][1] < 0:
                self.grid_v[b, i, j][1] = 0
            if j > self.res[1] - 3 and self.grid_v[b, i, j][1] > 0:
                self.grid_v[b, i, j][1] = 0
        for b, p in self.x:
            Xp = self.x[b, p] / dx
            base = ti.cast(Xp - 0.5, ti.i32)
            fx = Xp - base
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
            new_v = ti.Vector.zero(ti.f32, 2)
            new_C = ti.Matrix.zero(ti.f32, 2, 2)
            for i, j in ti.static(ti.ndrange(3, 3)):
                offset = ti.Vector([i, j])
                dpos = offset - fx
                weight = w[i][0] * w[j][1]
                g_v = self.grid_v[b, base + offset]
                new_v += weight * g_v
                new_C += 4 * weight * g_v.outer_product(dpos) / dx
            self.v[b, p] = new_v
            self.x[b, p] += dt * self.v[b, p]
            self.J[b, p] *= 1 + dt * new_C.trace()
            self.C[b, p] = new_C

    def close(self):
        self._tree.destroy()


def pouring_scene(cfg: SimConfig, env: int) -> EnvSpec:
    """A full cup above-right of a target cup on the floor (slightly different per environment)."""
    cup = Body("cup", pose=(0.40 + 0.002 * (env % 5), 0.20, 0.0), shapes=open_box(0.07, 0.09, 0.02))
    target = Body("target", pose=(0.15, cfg.wall + 0.02, 0.0), shapes=open_box(0.12, 0.08, 0.02))
    return EnvSpec(bodies=[cup, target], water=[WaterBlock((-0.035, 0.0), (0.035, 0.05), body="cup")])


SCENES = ("pouring", "world")


def _time_loop(fn, min_seconds: float) -> tuple[int, float]:
    fn(5)  # warm up / compile
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < min_seconds:
        fn(50)
        n += 50
    return n, time.perf_counter() - t0


def _setup(scene: str, B: int, dx: float, arch: str) -> tuple[SimConfig, list[EnvSpec]]:
    """The solver config and the B environments of a benchmark scene."""
    if scene == "pouring":
        cfg = SimConfig(n_envs=B, dx=dx, dt=0.4 * dx / 12.0, max_particles=int(0.0035 * 4 / dx**2) + 64, arch=arch)
        return cfg, [pouring_scene(cfg, b) for b in range(B)]
    from active.run import compose_config
    from sim.world import WorldConfig

    world = WorldConfig.from_mapping(compose_config([])["world"])
    return world.sim_config(B, arch=arch), [
        world.scene("target", (0.40 + 0.002 * (b % 5), 0.20, 0.0)) for b in range(B)
    ]


def bench(
    envs=(1, 8, 32), seconds: float = 0.5, dx: float = 0.01, arch: str = "cpu", rounds: int = 3, scene: str = "pouring"
) -> list[dict]:
    if scene not in SCENES:
        raise ValueError(f"scene = {scene!r}: allowed one of {SCENES}")
    init_taichi(arch)
    rows = []
    for B in envs:
        cfg, specs = _setup(scene, B, dx, arch)
        solver = MPMSolver(cfg)
        solver.reset(specs)
        n_p = int(solver.particle_counts()[0])
        # the cup moves during the measurement: colliders with velocity, as in a pour
        solver.set_body_velocity(0, np.tile([[-0.1, 0.0]], (B, 1)), np.full(B, 0.3))
        x0 = np.stack([solver.positions(b)[:n_p] for b in range(B)])
        ref = ReferenceMPM88(
            B, n_p, cfg.res, cfg.dx, cfg.dt, cfg.rho * cfg.sound_speed**2, cfg.dx**2 / cfg.ppc, cfg.rho, cfg.gravity, x0
        )

        def ref_step(k, ref=ref):
            for _ in range(k):
                ref.substep()
            ti.sync()

        # alternate the two measurements and keep each one's best round, so that a busy machine
        # penalises neither side more than the other
        ours, reference = 0.0, 0.0
        for _ in range(rounds):
            steps, secs = _time_loop(solver.step, seconds / rounds)
            ours = max(ours, B * n_p * steps / secs)
            r_steps, r_secs = _time_loop(ref_step, seconds / rounds)
            reference = max(reference, B * n_p * r_steps / r_secs)
        solver.close()
        ref.close()
        rows.append(
            {
                "scene": scene,
                "B": B,
                "particles_per_env": n_p,
                "grid": list(cfg.res),
                "solver_pss": ours,
                "reference_pss": reference,
                "ratio": ours / reference,
                "solver_substeps_per_s": ours / (B * n_p),
                "reference_substeps_per_s": reference / (B * n_p),
            }
        )
    base = rows[0]["solver_pss"] if rows and rows[0]["B"] == 1 else None
    for r in rows:
        r["speedup_vs_B1"] = r["solver_pss"] / base if base else None
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.sim_solver",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--out", default="bench_sim.json")
    ap.add_argument("--envs", type=int, nargs="+", default=[1, 8, 32])
    ap.add_argument("--seconds", type=float, default=3.0, help="measuring time per case and side")
    ap.add_argument("--dx", type=float, default=0.01)
    ap.add_argument("--arch", default="cpu")
    ap.add_argument(
        "--scene",
        default="pouring",
        choices=SCENES,
        help="pouring: the first benchmark scene (ppc 4); world: the default world's target-world scene",
    )
    args = ap.parse_args(argv)
    rows = bench(args.envs, args.seconds, args.dx, args.arch, scene=args.scene)
    print(
        f"{'B':>4} {'particles':>9} {'grid':>9} {'solver p-sub/s':>15} {'reference p-sub/s':>18} "
        f"{'ratio':>6} {'vs B=1':>7}"
    )
    for r in rows:
        sp = f"{r['speedup_vs_B1']:.2f}x" if r["speedup_vs_B1"] else "-"
        print(
            f"{r['B']:>4} {r['particles_per_env']:>9} {'x'.join(map(str, r['grid'])):>9} {r['solver_pss']:>15.3g} "
            f"{r['reference_pss']:>18.3g} {r['ratio']:>6.2f} {sp:>7}"
        )
    meta = {
        "scene": args.scene,
        "arch": args.arch,
        "dx": args.dx if args.scene == "pouring" else None,
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
        "targets": {"ratio_min": 0.7, "B32_over_B1_min": 2.0},
    }
    safeio.write_json(args.out, {"meta": meta, "rows": rows})
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
