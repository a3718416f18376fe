"""Batched weakly compressible MLS-MPM water with kinematic signed-distance colliders.

Physics (Hu et al. 2018, MLS-MPM; the J-based fluid of Taichi's mpm88): APIC transfers, quadratic
B-splines, pressure p = K (1 - J) with bulk modulus K = rho c^2, explicit substeps bounded by the
acoustic CFL condition (``SimConfig.dt_max``).

Batching: B independent environments share one set of fields with a leading environment axis. On the
CPU one kernel launch advances every running environment by many substeps, one task per environment
(clear grid, body update + particle-to-grid, grid update, grid-to-particle, in a fixed particle order;
environments in parallel across threads), so runs are bit reproducible and one environment's motion
cannot change another's numbers (a single large environment instead splits each stage over the threads,
with the same per-node order of additions: the same bits). On the GPU one launch per substep runs the
stages as consecutive offloaded loops, in parallel over grid rows and particles, and particle-to-grid
scatters with atomics.

Colliders: tank walls are half-planes; bodies are kinematic rigid bodies (pose + linear and angular
velocity, prescribed by a controller) made of boxes, capsules and ellipses (2D). Water-wall contact
is separating: at grid nodes inside a collider the velocity relative to the collider loses its
inflowing normal part, and the tangential part keeps slipping with Coulomb friction ``friction``
(0 = free slip, the usual choice when the viscous boundary layer is far below the grid spacing).
A particle that still ends a substep inside a collider is projected to its surface along the SDF
gradient with the same velocity rule, so thin container walls (>= 2 cells) do not leak.

The transfers, the grid update and the collider query are Taichi functions shared with the
differentiable solver (``sim.engine.stencil``, ``sim.engine.colliders``); this module schedules them.
"""

import logging
from typing import Sequence

import numpy as np
import taichi as ti

from .backend import init_taichi
from .colliders import Colliders, to_frame
from .config import ConfigError, SimConfig
from .scene import EnvSpec, sample_water
from .stencil import Stencil

log = logging.getLogger(__name__)

#: CPU: particles per environment above which fewer environments than threads run split over the threads
#: (``MPMSolver.step``: each environment's particle-to-grid split into row slabs, one per thread). On 2 cores the
#: split substep ran 1.1-1.35x the one-task path at 16,000 particles, 1.0-1.45x at 8,192 and 0.8-1.1x at 4,563 (best
#: round against best round; ``benchmarks.sim_split``, BENCHMARKS.md, "One 3D environment on both threads"); the
#: worlds' scenes (at most 2,048) always run one task each.
_SPLIT_ENV_PARTICLES = 6000
#: dimensions whose particle-grid transfers run factored: the stencil's per-node affine terms (mv + A (o - fx) dx to
#: the grid, sum w g_v (o - fx)^T back) as sums over the offset o's digits, additions instead of matrix products.
#: The same equations, rounded differently (``sim.engine.stencil``): 1.45-1.95x the one-task speed of the 3D dam
#: break (16,000-128,000 particles, 27-node stencil), 1.11-1.36x on the default world's 2D scene at B = 32
#: (``benchmarks.sim_split``, BENCHMARKS.md, "factored transfers, 3D and 2D"). Changing it changes every pour's
#: bits: bump ``sim.engine.config.NUMERICS_REVISION`` and regenerate the shipped data (``python -m dynamics.shipped``).
#: Read when a solver is built (``benchmarks.sim_split`` sets it before building one).
_FACTORED_TRANSFERS = (2, 3)


@ti.func
def _not_finite(v):
    """NaN/inf test on the bit pattern: survives fast-math, which folds ``v != v`` to False."""
    return (ti.bit_cast(v, ti.u32) & ti.u32(0x7F800000)) == ti.u32(0x7F800000)


@ti.data_oriented
class MPMSolver:
    """B environments of MLS-MPM water; see the module docstring for the model."""

    def __init__(self, cfg: SimConfig):
        cfg.validate()
        self.cfg = cfg
        self.arch = init_taichi(cfg.arch)
        self.dim = cfg.dim
        self.B, self.N = cfg.n_envs, cfg.max_particles
        self.NB, self.NS = cfg.max_bodies, cfg.max_shapes
        self.res = cfg.res
        self.serial_p2g = bool(cfg.deterministic and self.arch == "cpu")
        # CPU execution (deterministic): one task runs whole substeps of one environment (grid phase, then
        # grid to particle), ``n`` of them per launch (``step``), because on this class of machine the
        # parallelism of a launch of ~1 ms was lost: Taichi 1.7 compiles a top-level CPU range-for into one
        # contiguous block per thread of at least 512 iterations (its make_cpu_multithreaded_range_for
        # pass), so a loop over B < 1024 environments ran on one thread, and the other thread of a short
        # loop often woke too late to take its block (BENCHMARKS.md, simulator throughput). The loops run over
        # threads x blocks instead, each block exactly one thread's, holding the running environments
        # t, t + T, t + 2T, ... (interleaved, so that long trajectories at one end of a batch do not all land
        # on one thread). Scheduling only: every environment's arithmetic, and so every result, is the
        # same (tests/test_sim_solver.py).
        self.threads = int(ti.lang.impl.current_cfg().cpu_max_num_threads) if self.arch == "cpu" else 1
        self._env_block = max(-(-self.B // self.threads), 512)
        #: slabs of the split path (``_substep_split``): one per thread, at least 2 (so that one thread runs it too:
        #: tests)
        self._slabs = max(self.threads, 2)
        self._n_running = self.B
        #: the transfers (shared with the differentiable solver) and the particle constants
        self.stencil = Stencil(cfg, ti.f32, factored=cfg.dim in _FACTORED_TRANSFERS)
        self.time = 0.0
        self.specs: list[EnvSpec] = []
        self._place_fields()
        ti.sync()  # materialise now: Taichi validates pending fields lazily, and a closed solver's would fail
        self._body_state = np.zeros((self.B, self.NB, 6), np.float32)  # x, y, th, vx, vy, w
        self._schedule: ti.Ndarray | None = None  # (B, T, 3) target poses on the device (load_schedule)
        self._schedule_body = 0

    def _place_fields(self) -> None:
        """Every field in one tree: particles, per-environment flags and boxes, the grid, the colliders."""
        dim = self.dim
        fb = ti.FieldsBuilder()
        self.x = ti.Vector.field(dim, ti.f32)
        self.v = ti.Vector.field(dim, ti.f32)
        self.C = ti.Matrix.field(dim, dim, ti.f32)
        self.J = ti.field(ti.f32)
        fb.dense(ti.ij, (self.B, self.N)).place(self.x, self.v, self.C, self.J)
        self.n_part = ti.field(ti.i32)
        self.nan_flag = ti.field(ti.i32)
        self.pinned = ti.field(ti.i32)
        self.active = ti.field(ti.i32)  # 0: environment frozen (costs nothing, state kept as it is)
        self.run_order = ti.field(ti.i32)  # the running environments, in index order (CPU loops)
        fb.dense(ti.i, self.B).place(self.n_part, self.nan_flag, self.pinned, self.active, self.run_order)
        # grid nodes each environment's last particle-to-grid wrote: [lo, hi] per axis
        self.box_cur = ti.Vector.field(dim, ti.i32)
        self.box_cur_hi = ti.Vector.field(dim, ti.i32)
        fb.dense(ti.i, self.B).place(self.box_cur, self.box_cur_hi)
        # split path (``_substep_split``): the rows of thread t's slab are split_row[b, t] .. split_row[b, t + 1] - 1
        self.split_row = ti.field(ti.i32)
        fb.dense(ti.ij, (self.B, self._slabs + 1)).place(self.split_row)
        self.part_lo = ti.Vector.field(dim, ti.i32)  # each thread's box of written nodes (then box_cur)
        self.part_hi = ti.Vector.field(dim, ti.i32)
        fb.dense(ti.ij, (self.B, self._slabs)).place(self.part_lo, self.part_hi)
        self.row_count = ti.field(ti.i32)  # (b, thread, row): particles whose stencil starts in the row (balance)
        fb.dense(ti.ijk, (self.B, self._slabs, self.res[0])).place(self.row_count)
        self.grid_v = ti.Vector.field(dim, ti.f32)
        self.grid_m = ti.field(ti.f32)
        fb.dense(ti.axes(*range(dim + 1)), (self.B,) + self.res).place(self.grid_v, self.grid_m)
        #: tank walls and bodies: shapes, poses, velocities (``sim.engine.colliders``, shared with the
        #: differentiable solver); the bodies' cos, sin are refreshed each substep
        self.colliders = Colliders(self.cfg, self.B, self.NB, self.NS, fb)
        self._tree = fb.finalize()

    # ================================================================== set-up
    def reset(self, specs: Sequence[EnvSpec], slots: Sequence[int] | None = None) -> None:
        """Load one scene per environment: bodies, colliders, and freshly sampled water.

        Environment b samples its water jitter with the generator ``[sim.seed, slots[b]]`` (default
        ``slots[b] = b``): a scene run with the same slot in another batch gets the same particles, and
        so, environments being independent, the same results. Everything is checked before any field
        is written: counts against the capacities, water inside the tank, colliders inside the domain.
        """
        if len(specs) != self.B:
            raise ConfigError(f"reset: got {len(specs)} environment specs, sim.n_envs = {self.B}")
        slots = list(range(self.B)) if slots is None else [int(k) for k in slots]
        if len(slots) != self.B or min(slots) < 0:
            raise ConfigError(f"reset: slots must be {self.B} integers >= 0, got {slots}")
        if self.dim != 2 and any(s.bodies for s in specs):
            raise ConfigError("colliding bodies are implemented for sim.dim = 2 only (3D: tank walls only)")
        parts = np.zeros((self.B, self.N, self.dim), np.float32)
        n_part = np.zeros(self.B, np.int32)
        layout = self.colliders.empty_layout()
        for b, spec in enumerate(specs):
            if len(spec.bodies) > self.NB:
                raise ConfigError(f"env {b}: {len(spec.bodies)} bodies > sim.max_bodies = {self.NB}")
            pts = self._water(b, spec, slots[b])
            parts[b, : len(pts)] = pts
            n_part[b] = len(pts)
            self.colliders.pack_env(layout, b, spec.bodies)
        # --- all checks passed: write fields
        self.specs = list(specs)
        self.x.from_numpy(parts)
        self.v.from_numpy(np.zeros_like(parts))
        self.C.from_numpy(np.zeros((self.B, self.N, self.dim, self.dim), np.float32))
        self.J.from_numpy(np.ones((self.B, self.N), np.float32))
        self.n_part.from_numpy(n_part)
        self.nan_flag.fill(0)
        self.pinned.fill(0)
        self.set_active(np.ones(self.B, bool))
        self.colliders.write(layout)
        self._body_state = layout["state"]
        self.grid_v.fill(0.0)
        self.grid_m.fill(0.0)
        self._full_boxes()
        self.time = 0.0
        self._reported: set[int] = set()

    def _water(self, b: int, spec: EnvSpec, slot: int) -> np.ndarray:
        """Environment b's water particles, sampled with the generator [sim.seed, slot]; checked against the
        capacity and the tank interior."""
        cfg = self.cfg
        lo_w, hi_w = cfg.wall, [L - cfg.wall for L in cfg.domain]
        rng = np.random.default_rng([cfg.seed, slot])
        pts = sample_water(spec, cfg.dx, cfg.ppc, rng, cfg.jitter) if self.dim == 2 else _sample_nd(spec, cfg, rng)
        if len(pts) > self.N:
            raise ConfigError(
                f"env {b}: {len(pts)} particles > sim.max_particles = {self.N}; raise "
                f"sim.max_particles or use less water / a coarser sim.dx"
            )
        if len(pts) and (pts.min(0) < lo_w).any() or len(pts) and (pts.max(0) > np.asarray(hi_w)).any():
            raise ConfigError(
                f"env {b}: water outside the tank interior [{lo_w:g}, {hi_w}] m "
                f"(particles span {pts.min(0)} .. {pts.max(0)})"
            )
        return pts

    def _push_bodies(self) -> None:
        self.colliders.push(self._body_state)

    # ================================================================== bodies
    def body_poses(self, body: int) -> np.ndarray:
        """(B, 3) world poses (x, y, theta) of body ``body`` in every environment."""
        self._pull_bodies(velocities=False)
        return self._body_state[:, body, :3].copy()

    def all_body_poses(self) -> np.ndarray:
        """(B, max_bodies, 3) world poses of every body."""
        self._pull_bodies(velocities=False)
        return self._body_state[..., :3].copy()

    def set_body_velocity(self, body: int, vel: np.ndarray, omega: np.ndarray | None = None) -> None:
        """Prescribe the linear (B, 2) and angular (B,) velocity of a body; poses integrate it."""
        self._pull_bodies()
        self._body_state[:, body, 3:5] = np.asarray(vel, np.float32).reshape(self.B, 2)
        self._body_state[:, body, 5] = 0.0 if omega is None else np.asarray(omega, np.float32).reshape(self.B)
        self._push_bodies()

    def set_body_pose(self, body: int, pose: np.ndarray) -> None:
        """Teleport a body (B, 3) without moving water (for tests and resets)."""
        self._pull_bodies()
        self._body_state[:, body, :3] = np.asarray(pose, np.float32).reshape(self.B, 3)
        self._push_bodies()

    def track(self, body: int, target: np.ndarray, horizon: float) -> None:
        """Set body ``body``'s velocities so that it reaches ``target`` (B, 3) poses in ``horizon`` seconds.

        The same arithmetic as ``set_body_velocity((target - body_poses(body)) / horizon)`` (float64,
        then stored as float32), but in one kernel launch instead of nine field copies.
        """
        target = np.ascontiguousarray(target, np.float64).reshape(self.B, 1, 3)
        self._track(int(body), target, 0, float(horizon))

    def load_schedule(self, body: int, poses: np.ndarray) -> None:
        """Upload body ``body``'s target poses (B, T, 3) for every control tick, once.

        Why: the controller's per-tick call, :meth:`track_tick`, then reads its target where the
        solver runs; on a GPU no pose crosses the bus during a trajectory (a per-tick upload
        synchronises host and device every tick). ``track_tick(k, h)`` == ``track(body, poses[:, k], h)``.
        """
        poses = np.ascontiguousarray(poses, np.float64)
        if poses.ndim != 3 or poses.shape[0] != self.B or poses.shape[2] != 3:
            raise ValueError(f"load_schedule: expected ({self.B}, T, 3) poses, got shape {poses.shape}")
        self._schedule = ti.ndarray(ti.f64, shape=poses.shape)
        self._schedule.from_numpy(poses)
        self._schedule_body = int(body)

    def track_tick(self, k: int, horizon: float) -> None:
        """Steer the scheduled body towards its pose at tick ``k`` of :meth:`load_schedule` in ``horizon`` s."""
        if self._schedule is None or not 0 <= k < self._schedule.shape[1]:
            raise ValueError(f"track_tick: tick {k} outside the loaded schedule (load_schedule first)")
        self._track(self._schedule_body, self._schedule, int(k), float(horizon))

    @ti.kernel
    def _track(self, k: ti.i32, targets: ti.types.ndarray(dtype=ti.f64, ndim=3), tick: ti.i32, h: ti.f64):
        for b in range(self.B):
            if ti.static(self.dim == 2):
                for d in ti.static(range(2)):
                    self.colliders.body_vel[b, k][d] = ti.cast(
                        (targets[b, tick, d] - ti.cast(self.colliders.body_pos[b, k][d], ti.f64)) / h, ti.f32
                    )
            self.colliders.body_omega[b, k] = ti.cast(
                (targets[b, tick, 2] - ti.cast(self.colliders.body_rot[b, k], ti.f64)) / h, ti.f32
            )

    def _pull_bodies(self, velocities: bool = True) -> None:
        """Refresh the host copy; velocities too before a push (``track`` writes them on the device)."""
        self.colliders.pull(self._body_state, velocities)

    # ================================================================== stepping
    def set_active(self, mask: np.ndarray) -> None:
        """Freeze (False) or run (True) each environment; (B,) booleans.

        A frozen environment is skipped by every stage of the substep, so a batch whose trajectories
        have ended costs only what its running environments cost. Its particles, grid and bodies stay
        exactly as they were (time stands still for it) and it resumes from there when set running
        again; the other environments' numbers do not change (environments never interact).
        ``reset`` sets every environment running.
        """
        mask = np.asarray(mask, bool).reshape(-1)
        if mask.shape != (self.B,):
            raise ValueError(f"set_active: expected {self.B} booleans (one per environment), got shape {mask.shape}")
        self.active.from_numpy(mask.astype(np.int32))
        running = np.flatnonzero(mask).astype(np.int32)
        self._n_running = len(running)
        self.run_order.from_numpy(np.concatenate([running, np.full(self.B - len(running), -1, np.int32)]))

    def active_mask(self) -> np.ndarray:
        """(B,) booleans: which environments are running (see ``set_active``)."""
        return self.active.to_numpy().astype(bool)

    def step(self, n_substeps: int = 1, staged: bool = False) -> None:
        """Advance every environment by ``n_substeps`` substeps of ``cfg.dt``.

        On the CPU (deterministic) one launch runs all of them, each environment's in one task
        (``_advance_envs``); ``staged`` runs one launch per substep with one offloaded loop per stage
        instead (``_substep``: the same results, bit for bit; for ``benchmarks.sim_profile``'s per-stage
        times). When fewer environments run than there are threads and each holds more than
        ``_SPLIT_ENV_PARTICLES`` particles, the CPU splits every stage of each environment over the
        threads instead (``_substep_split``, one launch per substep; the same results, bit for bit).
        The GPU always runs staged, in parallel over particles and grid rows."""
        n = int(n_substeps)
        if self.serial_p2g and not staged and self._n_running > 0 and self._split():
            for _ in range(n):
                self._substep_split(self._n_running)
        elif self.serial_p2g and not staged:
            if n > 0 and self._n_running > 0:
                self._advance_envs(n, self._n_running)
        else:
            for _ in range(n):
                self._substep()
        self.time += n * self.cfg.dt

    def _split(self) -> bool:
        """Whether the CPU runs each environment's substep split over the threads (``step``)."""
        return self._n_running < self.threads and self.N > _SPLIT_ENV_PARTICLES

    def sync(self) -> None:
        """Wait until every launched kernel has finished (GPU launches are asynchronous; for timing)."""
        ti.sync()

    def advance(self, duration: float) -> int:
        """Advance by ``duration`` seconds (rounded to whole substeps); returns the substeps taken."""
        n = int(round(duration / self.cfg.dt))
        self.step(n)
        return n

    # ================================================================== queries
    def positions(self, env: int | None = None) -> np.ndarray | list[np.ndarray]:
        """Particle positions: (n_b, dim) for one environment, or a list over all."""
        x, n = self.x.to_numpy(), self.n_part.to_numpy()
        return x[env, : n[env]] if env is not None else [x[b, : n[b]] for b in range(self.B)]

    def velocities(self, env: int | None = None) -> np.ndarray | list[np.ndarray]:
        v, n = self.v.to_numpy(), self.n_part.to_numpy()
        return v[env, : n[env]] if env is not None else [v[b, : n[b]] for b in range(self.B)]

    def particle_counts(self) -> np.ndarray:
        return self.n_part.to_numpy()

    def count_in_regions(self, bodies: Sequence[int], lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Particles inside axis-aligned boxes given in body frames: (B, m) counts for m regions.

        Region r is ``lo[r] <= q <= hi[r]`` with q the particle position in body ``bodies[r]``'s frame
        (a body index of -1 means the world frame). A particle counts once, in the first region that
        holds it: regions can overlap (the controlled cup stuck tilted with its mouth over the target
        cup's), and fractions of the water must not add up to more than all of it."""
        m = len(bodies)
        out = np.zeros((self.B, m), np.int32)
        self._count_regions(
            np.asarray(bodies, np.int32),
            np.asarray(lo, np.float32).reshape(m, 2),
            np.asarray(hi, np.float32).reshape(m, 2),
            out,
        )
        return out

    def stability(self) -> dict[str, np.ndarray]:
        """Per-environment instability flags: NaN seen, particles pinned at the domain edge."""
        nan = self.nan_flag.to_numpy().astype(bool)
        pinned = self.pinned.to_numpy()
        return {"nan": nan, "pinned": pinned, "unstable": nan | (pinned > 0)}

    def report_unstable(self) -> np.ndarray:
        """Log each newly unstable environment once; returns the boolean unstable mask."""
        st = self.stability()
        for b in np.flatnonzero(st["unstable"]):
            if b not in self._reported:
                self._reported.add(int(b))
                log.warning(
                    "sim environment %d went unstable at t=%.3f s (nan=%s, pinned particles=%d); "
                    "its results are invalid",
                    b,
                    self.time,
                    bool(st["nan"][b]),
                    int(st["pinned"][b]),
                )
        return st["unstable"]

    def close(self) -> None:
        """Free the fields (kernels stay compiled for this process)."""
        if getattr(self, "_tree", None) is not None:
            self._tree.destroy()
            self._tree = None
        self._schedule = None

    # ================================================================== Taichi functions
    @ti.func
    def _p2g(self, b, p, r0, r1, rows: ti.template()):
        """Scatter particle p's mass and momentum to its 3^dim stencil; returns the stencil's first node.
        With ``rows`` only the stencil's nodes in grid rows r0 .. r1 - 1 (the split path's slab)."""
        return self.stencil.p2g(
            self.grid_v,
            self.grid_m,
            b,
            self.x[b, p],
            self.v[b, p],
            self.C[b, p],
            self.J[b, p],
            self.serial_p2g,
            rows,
            r0,
            r1,
        )

    @ti.kernel
    def _full_boxes(self):
        for b in range(self.B):
            for d in ti.static(range(self.dim)):
                self.box_cur[b][d] = 0
                self.box_cur_hi[b][d] = self.res[d] - 1

    @ti.func
    def _clear_node(self, I):
        self.grid_v[I] = ti.Vector.zero(ti.f32, self.dim)
        self.grid_m[I] = 0.0

    @ti.func
    def _update_node(self, I):
        """Momentum to velocity, gravity, collider boundary condition at grid node I = (b, i, j[, k]), in place."""
        self.stencil.update_node(
            self.grid_v, self.grid_m, self.grid_v, self.grid_m, I, self.colliders, self.colliders, 0
        )

    @ti.func
    def _for_active_nodes(self, b, i, fn: ti.template()):
        """Apply ``fn`` to the nodes of row (b, i) inside environment b's active box."""
        if self.box_cur[b][0] <= i and i <= self.box_cur_hi[b][0]:
            self._for_box_row(b, i, self.box_cur[b], self.box_cur_hi[b], fn)

    @ti.func
    def _for_box_row(self, b, i, lo, hi, fn: ti.template()):
        """Apply ``fn`` to the nodes (b, i, j[, k]) of row i with lo <= (j[, k]) <= hi."""
        if ti.static(self.dim == 2):
            for j in range(lo[1], hi[1] + 1):
                fn(ti.Vector([b, i, j]))
        else:
            for j in range(lo[1], hi[1] + 1):
                for k in range(lo[2], hi[2] + 1):
                    fn(ti.Vector([b, i, j, k]))

    @ti.func
    def _for_box_nodes(self, b, fn: ti.template()):
        """Apply ``fn`` to every node of environment b's active box, serially (inside a per-env task)."""
        for i in range(self.box_cur[b][0], self.box_cur_hi[b][0] + 1):
            self._for_active_nodes(b, i, fn)

    @ti.func
    def _begin_env(self, b):
        """Empty the environment's box (its particle-to-grid fills it) and move its bodies."""
        self._empty_box(b)
        self._move_bodies(b)

    @ti.func
    def _empty_box(self, b):
        """Environment b's box of written nodes, emptied (lo = res, hi = 0): running mins / maxes fill it."""
        self.box_cur[b] = ti.Vector([self.res[d] for d in ti.static(range(self.dim))])
        self.box_cur_hi[b] = ti.Vector.zero(ti.i32, self.dim)

    @ti.func
    def _move_bodies(self, b):
        """Move environment b's kinematic bodies by their prescribed velocities over one substep."""
        self.colliders.move(b)

    @ti.kernel
    def _substep(self):
        """One substep of every running environment, one offloaded loop per stage (the GPU's way; on the
        CPU ``step(staged=True)``, for per-stage times; ``_advance_envs`` runs the same per-environment
        arithmetic)."""
        # 1. clear the nodes the last particle-to-grid wrote (everything else is zero already);
        # 2. move the kinematic bodies by their prescribed velocities (so grid update and G2P see this
        #    substep's collider poses), then particle to grid, which makes the box of the nodes it
        #    writes the environment's active box;
        # 3. grid update over that box: momentum to velocity, gravity, colliders.
        # Grid loops visit only the active box: an empty tank costs nothing.
        if ti.static(self.serial_p2g):
            # CPU: one task per environment runs 1-3 (no atomics); environments interleaved over the
            # threads (__init__)
            for i in range(self.threads * self._env_block):
                b = self._interleaved(i, self._env_block, self.B)
                if b >= 0 and self.active[ti.max(b, 0)]:  # Taichi's `and` evaluates both sides
                    self._env_grid_phase(b)
        else:
            # GPU: each stage in parallel over rows (b, i) or particles; the box by atomics
            for b, i in ti.ndrange(self.B, self.res[0]):
                if self.active[b]:
                    self._for_active_nodes(b, i, self._clear_node)
            for b in range(self.B):
                if self.active[b]:
                    self._begin_env(b)
            for b, p in ti.ndrange(self.B, self.N):
                if p < self.n_part[b] and self.active[b]:
                    base = self._p2g(b, p, 0, 0, False)
                    ti.atomic_min(self.box_cur[b], base)
                    ti.atomic_max(self.box_cur_hi[b], base + 2)
            for b, i in ti.ndrange(self.B, self.res[0]):
                if self.active[b]:
                    self._for_active_nodes(b, i, self._update_node)
        # 4. grid to particle, advection, collider projection, safety clamp
        for b, p in ti.ndrange(self.B, self.N):
            if p < self.n_part[b] and self.active[b]:
                self._g2p(b, p)

    @ti.func
    def _env_grid_phase(self, b):
        """Stages 1-3 of a substep for environment b, serially: clear the nodes its last particle-to-grid
        wrote, move its bodies, particle to grid (its box of written nodes a running min / max), grid update."""
        self._for_box_nodes(b, self._clear_node)
        self._begin_env(b)
        lo, hi = self.box_cur[b], self.box_cur_hi[b]
        for p in range(self.n_part[b]):
            base = self._p2g(b, p, 0, 0, False)
            lo = ti.min(lo, base)
            hi = ti.max(hi, base + 2)
        self.box_cur[b], self.box_cur_hi[b] = lo, hi
        self._for_box_nodes(b, self._update_node)

    @ti.kernel
    def _advance_envs(self, n: ti.i32, n_running: ti.i32):
        """CPU: ``n`` whole substeps of every running environment, one task per environment (its grid and
        particles stay in cache), the running environments interleaved over the threads (``__init__``)."""
        for i in range(self.threads * self._env_block):
            j = self._interleaved(i, self._env_block, n_running)
            if j >= 0:
                b = self.run_order[ti.max(j, 0)]  # Taichi's `and` evaluates both sides
                for _ in range(n):
                    self._env_grid_phase(b)
                    for p in range(self.n_part[b]):
                        self._g2p(b, p)

    @ti.kernel
    def _substep_split(self, n_running: ti.i32):
        """CPU, fewer running environments than threads: one substep with each stage split over the
        threads, in two parallel loops (each ends at a barrier, and on a small scene the barriers, not the
        balance, decide the speed) with serial steps between them, which run on the launching thread.

        Thread t owns the grid rows of slab t (split_row[b, t] .. split_row[b, t + 1] - 1; slab 0 and the last
        are open-ended, so the slabs always cover the grid). In the first parallel loop it clears the rows of
        the last box in its slab, reads all particles in index order and adds only to its own rows, so each
        node receives the same additions in the same order as in ``_env_grid_phase``, then updates its rows'
        nodes (no other thread wrote them: the nodes outside the box of those it wrote are empty, which the
        update leaves alone), so the results are the same, bit for bit. Where the slabs split the rows only
        changes the balance: grid to particle counts each thread's particles per row, and the serial step
        between places the next substep's slabs."""
        big = ti.static(1 << 20)
        ti.loop_config(serialize=True)
        for k in range(n_running):  # the grid update reads this substep's collider poses
            self._move_bodies(self.run_order[k])
        for q in range(self._slabs * self._env_block):
            t = q // self._env_block
            k = q % self._env_block
            if k < n_running:
                b = self.run_order[k]
                r0 = -big if t == 0 else self.split_row[b, t]
                r1 = big if t == self._slabs - 1 else self.split_row[b, t + 1]
                for i in range(ti.max(r0, self.box_cur[b][0]), ti.min(r1, self.box_cur_hi[b][0] + 1)):
                    self._for_active_nodes(b, i, self._clear_node)
                lo = ti.Vector([self.res[d] for d in ti.static(range(self.dim))])
                hi = ti.Vector.zero(ti.i32, self.dim)
                for p in range(self.n_part[b]):
                    first = ti.cast(self.x[b, p][0] * (1.0 / self.cfg.dx) - 0.5, ti.i32)
                    if first + 3 >= r0 and first - 1 < r1:  # one row of slack for rounding; _p2g checks exactly
                        base = self._p2g(b, p, r0, r1, True)
                        lo = ti.min(lo, base)
                        hi = ti.max(hi, base + 2)
                self.part_lo[b, t], self.part_hi[b, t] = lo, hi
                for i in range(ti.max(r0, lo[0]), ti.min(r1, hi[0] + 1)):
                    self._for_box_row(b, i, lo, hi, self._update_node)
        ti.loop_config(serialize=True)
        for k in range(n_running):
            b = self.run_order[k]
            self._empty_box(b)
            for t in range(self._slabs):  # every particle was scattered by some thread: the box is the union
                self.box_cur[b] = ti.min(self.box_cur[b], self.part_lo[b, t])
                self.box_cur_hi[b] = ti.max(self.box_cur_hi[b], self.part_hi[b, t])
            self._place_slabs(b)
        for q in range(self._slabs * self._env_block):  # thread t: the t-th share of each environment's particles
            t = q // self._env_block
            k = q % self._env_block
            if k < n_running:
                b = self.run_order[k]
                n = self.n_part[b]
                for i in range(self.res[0]):
                    self.row_count[b, t, i] = 0
                for p in range(t * n // self._slabs, (t + 1) * n // self._slabs):
                    self._g2p(b, p)
                    first = ti.cast(self.x[b, p][0] * (1.0 / self.cfg.dx) - 0.5, ti.i32)
                    self.row_count[b, t, ti.math.clamp(first, 0, self.res[0] - 1)] += 1

    @ti.func
    def _place_slabs(self, b):
        """Place the inner slab boundaries split_row[b, 1 .. threads - 1] so that each slab holds about as
        many particles (by the row of their stencil's first node, as counted by the last grid to particle)."""
        n = 0
        for t in range(self._slabs):
            for i in range(self.res[0]):
                n += self.row_count[b, t, i]
        t = 1
        seen = 0
        for i in range(self.res[0]):
            for u in range(self._slabs):
                seen += self.row_count[b, u, i]
            while t < self._slabs and seen * self._slabs >= t * n:
                self.split_row[b, t] = i + 1
                t += 1
        while t < self._slabs:
            self.split_row[b, t] = self.res[0]
            t += 1

    @ti.func
    def _interleaved(self, q, block: ti.template(), count):
        """Item (0 .. count - 1) of CPU loop index q over ``threads x block`` (block >= count / threads), or
        -1: thread t's block holds items t, t + T, t + 2T, ... (``__init__``): how environments (block
        ``_env_block``, count B or the running ones) are spread."""
        t = q // block
        k = q % block
        j = k * self.threads + t
        if j >= count:
            j = -1
        return j

    @ti.func
    def _g2p(self, b, p):
        """Grid to particle p of environment b: velocity and affine field, advection, collider
        projection, volume ratio, NaN parking and the safety clamp."""
        dim = ti.static(self.dim)
        new_v, new_C, mass_near = self.stencil.g2p(self.grid_v, self.grid_m, b, self.x[b, p])
        xn, new_v = self.stencil.advect(b, self.x[b, p], new_v, self.colliders, self.colliders, 0)
        J = self.stencil.volume_ratio(self.J[b, p], new_C, mass_near)
        bad = _not_finite(J)
        for d in ti.static(range(dim)):
            bad = bad | _not_finite(xn[d]) | _not_finite(new_v[d])
        if bad:  # park the particle so indices stay valid; the env is flagged
            self.nan_flag[b] = 1
            for d in ti.static(range(dim)):
                xn[d] = 0.5 * self.cfg.domain[d]
            new_v = ti.Vector.zero(ti.f32, dim)
            new_C = ti.Matrix.zero(ti.f32, dim, dim)
            J = 1.0
        xn, clamped = self.stencil.keep_on_grid(xn)
        if clamped:
            self.pinned[b] += 1
        self.x[b, p] = xn
        self.v[b, p] = new_v
        self.C[b, p] = new_C
        self.J[b, p] = J

    @ti.kernel
    def _count_regions(
        self, bodies: ti.types.ndarray(), lo: ti.types.ndarray(), hi: ti.types.ndarray(), out: ti.types.ndarray()
    ):
        for b, p in ti.ndrange(self.B, self.N):
            if p < self.n_part[b]:
                counted = 0
                for r in range(bodies.shape[0]):
                    if counted == 0:
                        k = bodies[r]
                        q = self.x[b, p]
                        if k >= 0:
                            q = to_frame(q, self.colliders.body_pos[b, k], self.colliders.body_cs[b, k])
                        if lo[r, 0] <= q[0] and q[0] <= hi[r, 0] and lo[r, 1] <= q[1] and q[1] <= hi[r, 1]:
                            out[b, r] += 1
                            counted = 1


def _sample_nd(spec: EnvSpec, cfg: SimConfig, rng: np.random.Generator) -> np.ndarray:
    """World-frame water blocks in any dimension (no bodies): jittered sub-grid sampling."""
    k = int(round(cfg.ppc ** (1.0 / cfg.dim)))
    h = cfg.dx / k
    out = []
    for blk in spec.water:
        axes = [np.arange(max(1, int(round((b1 - b0) / h)))) for b0, b1 in zip(blk.lo, blk.hi)]
        grids = np.meshgrid(
            *[(a + 0.5) * (b1 - b0) / len(a) + b0 for a, b0, b1 in zip(axes, blk.lo, blk.hi)], indexing="ij"
        )
        pts = np.stack([g.ravel() for g in grids], 1)
        out.append(pts + rng.uniform(-cfg.jitter * h, cfg.jitter * h, size=pts.shape))
    return np.concatenate(out, 0).astype(np.float32) if out else np.zeros((0, cfg.dim), np.float32)
