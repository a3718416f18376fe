"""Differentiable MLS-MPM water (2D), with checkpointed reverse mode.

Why a second solver: the production solver (``sim.engine.mpm``) scatters particle-to-grid with plain,
non-atomic adds and overwrites its state in place, which Taichi's reverse mode cannot differentiate.
This one runs the production solver's transfers, grid update and collider query (the same Taichi
functions: ``sim.engine.stencil``, ``sim.engine.colliders``; the same ``SimConfig`` constants) in a form
Taichi's autodiff accepts:

* state lives in a segment buffer indexed by substep, ``x[s]`` -> ``x[s + 1]`` (no overwriting), and the
  grid keeps its momentum in and its velocity out apart;
* particle-to-grid accumulates with ``+=`` (parallel over environments, serial over one
  environment's particles, as on the production CPU path: forward AND backward are deterministic);
* the geometry comes as arguments: kinematic bodies (``sim.engine.scene.Body``, shapes in body frames) of
  which the ``driven`` ones follow a pose and velocity given per substep (differentiable inputs) and the
  others stay at their poses; and ``regions``, boxes each in a frame whose pose per environment is a
  differentiable input, in which ``outcome`` measures the soft fraction of each environment's water;
* signed distances avoid the non-differentiable point of ``norm`` at 0 (sqrt of max(d2, tiny)).

Checkpointing: the buffer holds K + 1 states (K = ``checkpoint_every`` substeps). The forward pass
stores the state at every K-th substep in a checkpoint field; the backward pass walks the segments
in reverse, recomputes each from its checkpoint, and runs the substep adjoints in reverse order.
Memory is O(T / K + K) particle states (plus 6 reals per environment, driven body and substep for the
trajectories); the cost is one extra forward pass.

Precision: f64 by default (field dtype set explicitly; the process-wide default stays f32 for the
production solver). f32 works but makes finite-difference checks noisy. Taichi types the Python float
constants (dx, dt, the particle mass, the geometry) as f32 in either precision.
"""

import math
from typing import Sequence

import numpy as np
import taichi as ti

from .backend import init_taichi
from .colliders import Colliders
from .config import ConfigError, SimConfig
from .scene import Body
from .stencil import Stencil

#: reals stored per particle state: x (2), v (2), C (4), J (1)
REALS_PER_PARTICLE = 9
#: reals stored per grid node: momentum in (2), mass (1), velocity out (2); + 1 with sim.boundary_density
REALS_PER_NODE = 5
#: reals per environment, driven body and substep: pose (3), velocity (3)
REALS_PER_DRIVEN = 6
#: reals per environment and region: the frame's pose (3), the soft fraction (1)
REALS_PER_REGION = 4


@ti.func
def _ramp(u):
    """C2 smooth step from 0 at u <= -1 to 1 at u >= 1 (the min-jerk polynomial)."""
    t = ti.math.clamp(0.5 * (u + 1.0), 0.0, 1.0)
    return t * t * t * (10.0 - 15.0 * t + 6.0 * t * t)


@ti.data_oriented
class DiffMPM:
    """``sc.n_envs`` environments of 2D water among ``bodies``; fields sized for ``max_substeps`` and
    ``checkpoint_every`` (module docstring)."""

    def __init__(
        self,
        sc: SimConfig,
        bodies: Sequence[Body],
        n_particles: int,
        max_substeps: int,
        checkpoint_every: int,
        *,
        driven: Sequence[int] = (),
        regions: Sequence[tuple[Sequence[float], Sequence[float]]] = (),
        precision: str = "f64",
        arch: str = "cpu",
        soft_width: float | None = None,
    ):
        """``driven``: indices into ``bodies`` of the bodies whose pose and velocity ``run_forward`` takes per
        substep (their poses here are not used); ``regions``: (lo, hi) corners of each region's box in its
        frame; ``soft_width``: m over which a region's inside weight ramps (default dx / 2)."""
        if sc.dim != 2:
            raise ConfigError(f"sim.dim = {sc.dim}: the differentiable solver is 2D only")
        if sc.box_normals != "analytic":
            raise ConfigError(
                f"sim.box_normals = {sc.box_normals!r}: the differentiable solver allows only "
                "'analytic' (a central-difference normal makes its rollouts non-smooth at the "
                "finite-difference scale; BENCHMARKS.md, differentiable pours)"
            )
        self.driven = tuple(int(k) for k in driven)
        if any(not 0 <= k < len(bodies) for k in self.driven) or len(set(self.driven)) < len(self.driven):
            raise ConfigError(f"driven = {list(driven)}: allowed distinct indices into the {len(bodies)} bodies")
        self.sc = sc
        self.arch = init_taichi(arch)
        self.real = ti.f64 if precision == "f64" else ti.f32
        self.np_real = np.float64 if precision == "f64" else np.float32
        self.B, self.N = sc.n_envs, n_particles
        self.K = int(checkpoint_every)
        self.T_max = int(max_substeps)
        self.n_ck = int(math.ceil(self.T_max / self.K))
        self.res = sc.res
        self.soft_width = 0.5 * sc.dx if soft_width is None else float(soft_width)
        self.regions = [(list(map(float, lo)), list(map(float, hi))) for lo, hi in regions]
        self.stencil = Stencil(sc, self.real)
        self._place_fields()
        self._place_geometry(list(bodies))
        ti.sync()

    def _place_fields(self) -> None:
        """The differentiated fields (one tree with adjoints) and the checkpoints (a tree of their own)."""
        real, B, N, K1 = self.real, self.B, self.N, self.K + 1
        fb = ti.FieldsBuilder()
        self.x = ti.Vector.field(2, real, needs_grad=True)
        self.v = ti.Vector.field(2, real, needs_grad=True)
        self.C = ti.Matrix.field(2, 2, real, needs_grad=True)
        self.J = ti.field(real, needs_grad=True)
        fb.dense(ti.ijk, (K1, B, N)).place(self.x, self.v, self.C, self.J)
        self.grid_v_in = ti.Vector.field(2, real, needs_grad=True)
        self.grid_m = ti.field(real, needs_grad=True)
        self.grid_v_out = ti.Vector.field(2, real, needs_grad=True)
        grid = [self.grid_v_in, self.grid_m, self.grid_v_out]
        self.grid_rho = None  # mass for the density estimate: only with sim.boundary_density
        if self.sc.boundary_density:
            self.grid_rho = ti.field(real, needs_grad=True)
            grid.append(self.grid_rho)
        fb.dense(ti.ijk, (B,) + self.res).place(*grid)
        self.body_pose = self.body_vel = None  # driven bodies: pose and velocity per substep
        if self.driven:
            self.body_pose = ti.Vector.field(3, real, needs_grad=True)
            self.body_vel = ti.Vector.field(3, real, needs_grad=True)
            fb.dense(ti.ijk, (self.T_max, B, len(self.driven))).place(self.body_pose, self.body_vel)
        self.region_pose = self.soft = None  # each region's frame and the soft fraction of the water inside
        if self.regions:
            self.region_pose = ti.Vector.field(3, real, needs_grad=True)
            self.soft = ti.field(real, needs_grad=True)
            fb.dense(ti.ij, (B, len(self.regions))).place(self.region_pose, self.soft)
        self.n_part = ti.field(ti.i32)
        fb.dense(ti.i, B).place(self.n_part)
        fb.lazy_grad()
        self._tree = fb.finalize()
        # checkpoints in a tree of their own: lazy_grad gives every real field of a tree an adjoint,
        # and checkpoints are only copied, never differentiated
        ck = ti.FieldsBuilder()
        self.ck_x = ti.Vector.field(2, real)
        self.ck_v = ti.Vector.field(2, real)
        self.ck_C = ti.Matrix.field(2, 2, real)
        self.ck_J = ti.field(real)
        ck.dense(ti.ijk, (self.n_ck, B, N)).place(self.ck_x, self.ck_v, self.ck_C, self.ck_J)
        self._ck_tree = ck.finalize()
        # the particle state of a slot and its checkpoint copy, field by field (the copy kernels loop over these)
        self._state = (self.x, self.v, self.C, self.J)
        self._ck = (self.ck_x, self.ck_v, self.ck_C, self.ck_J)
        #: the grid mass the density estimate reads: the ghost mass with sim.boundary_density
        self._density_mass = self.grid_rho if self.sc.boundary_density else self.grid_m

    def _place_geometry(self, bodies: list[Body]) -> None:
        """The colliders (not differentiated: a tree of their own), every environment's the same."""
        geo = ti.FieldsBuilder()
        self.colliders = Colliders(
            self.sc, self.B, max(len(bodies), 1), max(sum(len(b.shapes) for b in bodies), 1), geo, self.real
        )
        self._geo_tree = geo.finalize()
        layout = self.colliders.empty_layout()
        for b in range(self.B):
            self.colliders.pack_env(layout, b, bodies, placed_later=self.driven)
        self.colliders.fix_layout(layout)
        self.colliders.write(layout)

    # ================================================================== memory
    @staticmethod
    def memory_bytes(
        n_envs: int,
        n_particles: int,
        substeps: int,
        checkpoint_every: int,
        res: tuple[int, int],
        precision: str = "f64",
        *,
        boundary_density: bool,
        n_driven: int = 1,
        n_regions: int = 2,
    ) -> int:
        """Bytes of Taichi fields plus the host-side trajectory arrays for these sizes (the colliders, a few
        hundred bytes, aside).

        ``boundary_density``: the world's ``sim.boundary_density``, which adds a grid field; ``n_driven``,
        ``n_regions``: as many driven bodies and regions (the defaults keep the callers written before these
        arguments working: one driven body, two regions).
        """
        r = 8 if precision == "f64" else 4
        K = min(int(checkpoint_every), int(substeps))
        per_state = n_envs * n_particles * REALS_PER_PARTICLE * r
        segment = (K + 1) * per_state * 2  # values + adjoints
        checkpoints = math.ceil(substeps / K) * per_state
        grid = n_envs * res[0] * res[1] * (REALS_PER_NODE + bool(boundary_density)) * r * 2
        driven = substeps * n_envs * n_driven * REALS_PER_DRIVEN * r * 2  # values + adjoints
        regions = n_envs * n_regions * REALS_PER_REGION * r * 2
        counts = n_envs * 4  # the i32 particle counts
        host = substeps * n_envs * n_driven * REALS_PER_DRIVEN * 8 * 3  # trajectories and their two adjoint copies
        return int(segment + checkpoints + grid + driven + regions + counts + host)

    def close(self) -> None:
        for name in ("_tree", "_ck_tree", "_geo_tree"):
            if getattr(self, name, None) is not None:
                getattr(self, name).destroy()
                setattr(self, name, None)

    # ================================================================== body frames at substep t
    @ti.func
    def origin(self, b, t, k):
        """Body k's origin in environment b at substep t: its input if driven, else where it stands."""
        o = ti.cast(self.colliders.body_pos[b, k], self.real)
        for j in ti.static(range(len(self.driven))):
            if ti.cast(k, ti.i32) == self.driven[j]:
                pose = self.body_pose[t, b, j]
                o = ti.Vector([pose[0], pose[1]])
        return o

    @ti.func
    def rotation(self, b, t, k):
        cs = ti.cast(self.colliders.body_cs[b, k], self.real)
        for j in ti.static(range(len(self.driven))):
            if ti.cast(k, ti.i32) == self.driven[j]:
                pose = self.body_pose[t, b, j]
                cs = ti.Vector([ti.cos(pose[2]), ti.sin(pose[2])])
        return cs

    @ti.func
    def velocity(self, b, t, k):
        v = ti.cast(self.colliders.body_vel[b, k], self.real)
        w = ti.cast(self.colliders.body_omega[b, k], self.real)
        for j in ti.static(range(len(self.driven))):
            if ti.cast(k, ti.i32) == self.driven[j]:
                vel = self.body_vel[t, b, j]
                v = ti.Vector([vel[0], vel[1]])
                w = vel[2]
        return v, w

    # ================================================================== kernels
    @ti.kernel
    def clear_grid(self):
        for I in ti.grouped(self.grid_m):
            self.grid_v_in[I] = ti.Vector.zero(self.real, 2)
            self.grid_m[I] = 0.0
            self.grid_v_out[I] = ti.Vector.zero(self.real, 2)
            self.grid_v_in.grad[I] = ti.Vector.zero(self.real, 2)
            self.grid_m.grad[I] = 0.0
            self.grid_v_out.grad[I] = ti.Vector.zero(self.real, 2)
            if ti.static(self.sc.boundary_density):
                self.grid_rho[I] = 0.0
                self.grid_rho.grad[I] = 0.0

    @ti.kernel
    def substep(self, s: ti.i32, t: ti.i32):
        """State slot s -> s + 1 with the bodies at their poses of global substep t."""
        # 1. particle to grid: one task per environment, particles in a fixed order (deterministic)
        ti.loop_config(block_dim=1)
        for b in range(self.B):
            for p in range(self.n_part[b]):
                self.stencil.p2g(
                    self.grid_v_in,
                    self.grid_m,
                    b,
                    self.x[s, b, p],
                    self.v[s, b, p],
                    self.C[s, b, p],
                    self.J[s, b, p],
                    False,
                    False,
                    0,
                    0,
                )
        # 2. grid update: momentum to velocity, gravity, colliders
        for I in ti.grouped(self.grid_m):
            self.stencil.update_node(
                self.grid_v_in, self.grid_m, self.grid_v_out, self.grid_rho, I, self.colliders, self, t
            )
        # 3. grid to particle, advection, collider projection, position clamp, volume ratio
        ti.loop_config(block_dim=1)
        for b in range(self.B):
            for p in range(self.n_part[b]):
                xp = self.x[s, b, p]
                new_v, new_C, mass_near = self.stencil.g2p(self.grid_v_out, self._density_mass, b, xp)
                xn, new_v = self.stencil.advect(b, xp, new_v, self.colliders, self, t)
                xn, _ = self.stencil.keep_on_grid(xn)
                self.x[s + 1, b, p] = xn
                self.v[s + 1, b, p] = new_v
                self.C[s + 1, b, p] = new_C
                self.J[s + 1, b, p] = self.stencil.volume_ratio(self.J[s, b, p], new_C, mass_near)

    @ti.func
    def _region_weight(self, pose, r: ti.template(), p):
        """Smooth inside-weight of p for region r in its frame at ``pose``."""
        cs, sn = ti.cos(pose[2]), ti.sin(pose[2])
        d = p - ti.Vector([pose[0], pose[1]])
        q = ti.Vector([cs * d[0] + sn * d[1], -sn * d[0] + cs * d[1]])
        lo, hi = ti.static(self.regions[r])
        inv_w = ti.static(1.0 / self.soft_width)
        return (
            _ramp((q[0] - lo[0]) * inv_w)
            * _ramp((hi[0] - q[0]) * inv_w)
            * _ramp((q[1] - lo[1]) * inv_w)
            * _ramp((hi[1] - q[1]) * inv_w)
        )

    @ti.kernel
    def outcome(self, s: ti.i32):
        """Soft fraction of each environment's water inside each region."""
        ti.loop_config(block_dim=1)
        for b in range(self.B):
            inv_n = 1.0 / ti.cast(ti.max(self.n_part[b], 1), self.real)
            for p in range(self.n_part[b]):
                xp = self.x[s, b, p]
                for r in ti.static(range(len(self.regions))):
                    self.soft[b, r] += inv_n * self._region_weight(self.region_pose[b, r], r, xp)

    # ---- slot / checkpoint copies (not differentiated)
    @ti.kernel
    def save_checkpoint(self, s: ti.i32, c: ti.i32):
        for b, p in ti.ndrange(self.B, self.N):
            for f, ck in ti.static(zip(self._state, self._ck)):
                ck[c, b, p] = f[s, b, p]

    @ti.kernel
    def load_checkpoint(self, c: ti.i32, s: ti.i32):
        for b, p in ti.ndrange(self.B, self.N):
            for f, ck in ti.static(zip(self._state, self._ck)):
                f[s, b, p] = ck[c, b, p]

    @ti.kernel
    def move_grad(self, src: ti.i32, dst: ti.i32):
        """Adjoint of slot src becomes the adjoint of slot dst (segment boundary in the backward pass)."""
        for b, p in ti.ndrange(self.B, self.N):
            for f in ti.static(self._state):
                f.grad[dst, b, p] = f.grad[src, b, p]

    @ti.kernel
    def clear_particle_grads(self, keep: ti.i32):
        """Zero the adjoints of every slot except ``keep`` (-1: all)."""
        for s, b, p in self.J:
            if s != keep:
                self.x.grad[s, b, p] = ti.Vector.zero(self.real, 2)
                self.v.grad[s, b, p] = ti.Vector.zero(self.real, 2)
                self.C.grad[s, b, p] = ti.Matrix.zero(self.real, 2, 2)
                self.J.grad[s, b, p] = 0.0

    @ti.kernel
    def load_state(self, x0: ti.types.ndarray(), n_part: ti.types.ndarray()):
        """Initial state in slot 0: positions x0 (B, N, 2), at rest, uncompressed."""
        for b, p in ti.ndrange(self.B, self.N):
            self.x[0, b, p] = ti.Vector([x0[b, p, 0], x0[b, p, 1]], self.real)
            self.v[0, b, p] = ti.Vector.zero(self.real, 2)
            self.C[0, b, p] = ti.Matrix.zero(self.real, 2, 2)
            self.J[0, b, p] = 1.0
        for b in range(self.B):
            self.n_part[b] = n_part[b]

    # ================================================================== drivers
    def _segments(self, substeps: int) -> list[tuple[int, int]]:
        """(first global substep, length) of each checkpoint segment."""
        return [(t0, min(self.K, substeps - t0)) for t0 in range(0, substeps, self.K)]

    def run_forward(
        self, x0: np.ndarray, n_part: np.ndarray, poses: np.ndarray, vels: np.ndarray, region_poses: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Simulate ``poses.shape[1]`` substeps; returns the soft fractions (B, regions) and the final x (B, N, 2).

        ``poses``, ``vels``: (B, S, driven, 3) each driven body's pose (x, y, theta) and velocity (vx, vy,
        omega) during each substep; ``region_poses``: (B, regions, 3) each region's frame. Leaves the last
        segment in the buffer and every segment start in the checkpoint field, ready for ``run_backward``.
        """
        S = poses.shape[1]
        assert S <= self.T_max and poses.shape == vels.shape == (self.B, S, len(self.driven), 3)
        self._S = S
        if self.driven:
            for field, given in ((self.body_pose, poses), (self.body_vel, vels)):
                full = np.zeros((self.T_max, self.B, len(self.driven), 3), self.np_real)
                full[:S] = given.transpose(1, 0, 2, 3)
                field.from_numpy(full)
        if self.regions:
            self.region_pose.from_numpy(np.asarray(region_poses, self.np_real).reshape(self.B, len(self.regions), 3))
        self.load_state(np.ascontiguousarray(x0, self.np_real), np.asarray(n_part, np.int32))
        last = 0
        for c, (t0, L) in enumerate(self._segments(S)):
            if c > 0:
                self._copy_slot(last, 0)  # the next segment starts from this one's end state
            self.save_checkpoint(0, c)
            for s in range(L):
                self.clear_grid()
                self.substep(s, t0 + s)
            last = L
        self._last = last
        soft = np.zeros((self.B, 0))
        if self.regions:
            self.soft.fill(0.0)
            self.outcome(last)
            soft = self.soft.to_numpy()
        return soft, self._slot_positions(last)

    @ti.kernel
    def _copy_slot(self, src: ti.i32, dst: ti.i32):
        for b, p in ti.ndrange(self.B, self.N):
            self.x[dst, b, p] = self.x[src, b, p]
            self.v[dst, b, p] = self.v[src, b, p]
            self.C[dst, b, p] = self.C[src, b, p]
            self.J[dst, b, p] = self.J[src, b, p]

    @ti.kernel
    def _read_slot(self, s: ti.i32, out: ti.types.ndarray()):
        for b, p in ti.ndrange(self.B, self.N):
            for d in ti.static(range(2)):
                out[b, p, d] = self.x[s, b, p][d]

    def _slot_positions(self, s: int) -> np.ndarray:
        out = np.zeros((self.B, self.N, 2), self.np_real)
        self._read_slot(s, out)
        return out

    @ti.kernel
    def _read_slot_grad(self, s: ti.i32, out: ti.types.ndarray()):
        for b, p in ti.ndrange(self.B, self.N):
            for d in ti.static(range(2)):
                out[b, p, d] = self.x.grad[s, b, p][d]

    def run_backward(self, d_soft: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Adjoint of the last ``run_forward`` for the seeds d objective / d soft fraction (B, regions).

        Returns the gradients w.r.t. the driven bodies' poses and velocities per substep (B, S, driven, 3),
        the regions' poses (B, regions, 3) and the initial particle positions (B, N, 2).
        """
        S = self._S
        segs = self._segments(S)
        for f in (self.body_pose, self.body_vel, self.region_pose):
            if f is not None:
                f.grad.fill(0.0)
        self.clear_particle_grads(-1)
        if self.regions:
            self.soft.grad.from_numpy(np.asarray(d_soft, self.np_real).reshape(self.B, len(self.regions)))
            self.outcome.grad(self._last)
        for c in range(len(segs) - 1, -1, -1):
            t0, L = segs[c]
            if c < len(segs) - 1:
                # the adjoint of this segment's end state is the adjoint of the next segment's start
                self.move_grad(0, L)
                self.clear_particle_grads(L)
                self.load_checkpoint(c, 0)
                for s in range(L):  # recompute the segment
                    self.clear_grid()
                    self.substep(s, t0 + s)
            for s in range(L - 1, -1, -1):
                self.clear_grid()
                self.substep(s, t0 + s)  # grid state of this substep
                self.substep.grad(s, t0 + s)
        g_x0 = np.zeros((self.B, self.N, 2), self.np_real)
        self._read_slot_grad(0, g_x0)
        shape = (self.B, S, len(self.driven), 3)
        g_pose, g_vel = np.zeros(shape), np.zeros(shape)
        if self.driven:
            g_pose = self.body_pose.grad.to_numpy()[:S].transpose(1, 0, 2, 3).astype(float)
            g_vel = self.body_vel.grad.to_numpy()[:S].transpose(1, 0, 2, 3).astype(float)
        g_region = np.zeros((self.B, len(self.regions), 3))
        if self.regions:
            g_region = self.region_pose.grad.to_numpy().astype(float)
        return g_pose, g_vel, g_region, g_x0.astype(float)
