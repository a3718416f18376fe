"""Differentiable MLS-MPM water for the source world, with checkpointed reverse mode.

Why a second solver: the production solver (``sim.mpm``) scatters particle-to-grid with plain,
non-atomic adds and overwrites its state in place, which Taichi's reverse mode cannot differentiate.
This one keeps the same physics (``sim.mpm`` docstring: weakly compressible J-based fluid, APIC,
quadratic B-splines, p = K (1 - J) with K = rho c^2, separating free-slip contact at grid nodes plus
projection of particles that end a substep inside a collider, the same position clamp) and the same
constants (``SimConfig``), in a form Taichi's autodiff accepts:

* state lives in a segment buffer indexed by substep, ``x[s]`` -> ``x[s + 1]`` (no overwriting);
* particle-to-grid accumulates with ``+=`` (parallel over environments, serial over one
  environment's particles, as on the production CPU path: forward AND backward are deterministic);
* colliders are fixed for the source world: tank walls (half-planes), the controlled cup (three
  boxes, pose and velocity per substep are differentiable INPUT fields) and the static target cup;
* signed distances avoid the non-differentiable point of ``norm`` at 0 (sqrt of max(d2, tiny)).

Checkpointing: the buffer holds K + 1 states (K = ``checkpoint_every`` substeps). The forward pass
stores the state at every K-th substep in a checkpoint field; the backward pass walks the segments
in reverse, recomputes each from its checkpoint, and runs the substep adjoints in reverse order.
Memory is O(T / K + K) particle states (plus 6 reals per environment per substep for the cup
trajectory); the cost is one extra forward pass.

Precision: f64 by default (field dtype set explicitly; the process-wide default stays f32 for the
production solver). f32 works but makes finite-difference checks noisy.
"""


import math

import numpy as np
import taichi as ti

from .backend import init_taichi
from .config import SimConfig
from .physics import affine_momentum, box_sdf, bspline_weights, ghost_mass, separate, update_volume_ratio
from ..world import WorldConfig

#: reals stored per particle state: x (2), v (2), C (4), J (1)
REALS_PER_PARTICLE = 9
#: reals stored per grid node: momentum in (2), mass (1), velocity out (2); + 1 with sim.boundary_density
REALS_PER_NODE = 5
#: reals per environment: end pose (3), soft fractions in the two cups (2)
REALS_PER_ENV = 5


@ti.func
def _ramp(u):
    """C2 smooth step from 0 at u <= -1 to 1 at u >= 1 (the min-jerk polynomial)."""
    t = ti.math.clamp(0.5 * (u + 1.0), 0.0, 1.0)
    return t * t * t * (10.0 - 15.0 * t + 6.0 * t * t)


@ti.data_oriented
class DiffMPM:
    """B source-world environments; fields sized for ``max_substeps`` and ``checkpoint_every``."""

    def __init__(self, world: WorldConfig, n_envs: int, n_particles: int, max_substeps: int,
                 checkpoint_every: int, precision: str = "f64", arch: str = "cpu", soft_width: float | None = None):
        sc: SimConfig = world.sim_config(n_envs)
        self.world, self.sc = world, sc
        self.stretch_rate = min(sc.dt / sc.stretch_relax, 1.0) if sc.stretch_relax > 0 else 0.0  # as MPMSolver's
        self.arch = init_taichi(arch)
        self.real = ti.f64 if precision == "f64" else ti.f32
        self.np_real = np.float64 if precision == "f64" else np.float32
        self.B, self.N = n_envs, n_particles
        self.K = int(checkpoint_every)
        self.T_max = int(max_substeps)
        self.n_ck = int(math.ceil(self.T_max / self.K))
        self.res = sc.res
        self.dx, self.dt = sc.dx, sc.dt
        self.p_vol = sc.dx**2 / sc.ppc
        self.p_mass = sc.rho * self.p_vol
        self.bulk = sc.rho * sc.sound_speed**2
        self.gravity = sc.gravity
        self.wall = sc.wall
        self.domain = sc.domain
        self.soft_width = 0.5 * sc.dx if soft_width is None else float(soft_width)
        # geometry (compile-time constants): boxes (body, cx, cy, hx, hy); body 0 = cup, 1 = target
        boxes = []
        for body, cup in ((0, world.controlled_cup), (1, world.target_cup)):
            for sh in cup.shapes():
                assert sh.kind == "box" and sh.angle == 0.0
                boxes.append((body, *sh.center, *sh.size))
        self.boxes = boxes
        self.n_cup_boxes = len(world.controlled_cup.shapes())
        self.target_pose = world.target_pose()
        assert self.target_pose[2] == 0.0, "the target cup stands upright"
        _, lo, hi = world.volume_regions()
        self.region_lo, self.region_hi = lo.tolist(), hi.tolist()

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
        if sc.boundary_density:
            self.grid_rho = ti.field(real, needs_grad=True)
            grid.append(self.grid_rho)
        fb.dense(ti.ijk, (B,) + self.res).place(*grid)
        self.cup_pose = ti.Vector.field(3, real, needs_grad=True)
        self.cup_vel = ti.Vector.field(3, real, needs_grad=True)
        fb.dense(ti.ij, (self.T_max, B)).place(self.cup_pose, self.cup_vel)
        self.end_pose = ti.Vector.field(3, real, needs_grad=True)  # controlled cup pose for the outcome
        self.soft_ctrl = ti.field(real, needs_grad=True)
        self.soft_tgt = ti.field(real, needs_grad=True)
        self.n_part = ti.field(ti.i32)
        fb.dense(ti.i, B).place(self.end_pose, self.soft_ctrl, self.soft_tgt, self.n_part)
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
        ti.sync()

    # ================================================================== memory
    @staticmethod
    def memory_bytes(n_envs: int, n_particles: int, substeps: int, checkpoint_every: int, res: tuple[int, int],
                     precision: str = "f64", *, boundary_density: bool) -> int:
        """Bytes of Taichi fields plus the host-side trajectory arrays for these sizes.

        ``boundary_density``: the world's ``sim.boundary_density``, which adds a grid field.
        """
        r = 8 if precision == "f64" else 4
        K = min(int(checkpoint_every), int(substeps))
        per_state = n_envs * n_particles * REALS_PER_PARTICLE * r
        segment = (K + 1) * per_state * 2  # values + adjoints
        checkpoints = math.ceil(substeps / K) * per_state
        grid = n_envs * res[0] * res[1] * (REALS_PER_NODE + bool(boundary_density)) * r * 2
        cup = substeps * n_envs * 6 * r * 2  # pose + velocity per substep, values + adjoints
        per_env = n_envs * (REALS_PER_ENV * 2 + 1) * r  # values + adjoints; the i32 particle count is padded to a real
        host = substeps * n_envs * 6 * 8 * 3  # trajectory and its two adjoint copies (float64)
        return int(segment + checkpoints + grid + cup + per_env + host)

    def close(self) -> None:
        for name in ("_tree", "_ck_tree"):
            if getattr(self, name, None) is not None:
                getattr(self, name).destroy()
                setattr(self, name, None)

    # ================================================================== geometry
    @ti.func
    def _box(self, q, s: ti.template()):
        """Signed distance and analytic outward normal of box s at q (``physics.box_sdf``), in the body frame."""
        _, cx, cy, hx, hy = ti.static(self.boxes[s])
        return box_sdf(q - ti.Vector([cx, cy], self.real), ti.Vector([hx, hy], self.real), self.real)

    @ti.func
    def _closest(self, b, t, p):
        """Signed distance to the nearest collider, its outward normal and its velocity at p.

        Same choice of collider as ``MPMSolver._contact`` where p is inside one (the deepest); box normals are
        analytic (``physics.box_sdf``).
        """
        real = self.real
        phi = ti.cast(1e9, real)
        n = ti.Vector.zero(real, 2)
        vc = ti.Vector.zero(real, 2)
        for d in ti.static(range(2)):
            lo = p[d] - self.wall
            hi = (self.domain[d] - self.wall) - p[d]
            if lo < phi:
                phi = lo
                n = ti.Vector.zero(real, 2)
                n[d] = 1.0
            if hi < phi:
                phi = hi
                n = ti.Vector.zero(real, 2)
                n[d] = -1.0
        # controlled cup: pose and velocity of this substep
        pose = self.cup_pose[t, b]
        vel = self.cup_vel[t, b]
        cs, sn = ti.cos(pose[2]), ti.sin(pose[2])
        r = p - ti.Vector([pose[0], pose[1]])
        q = ti.Vector([cs * r[0] + sn * r[1], -sn * r[0] + cs * r[1]])
        for s in ti.static(range(self.n_cup_boxes)):
            ps, nl = self._box(q, s)
            if ps < phi:
                phi = ps
                n = ti.Vector([cs * nl[0] - sn * nl[1], sn * nl[0] + cs * nl[1]])
                vc = ti.Vector([vel[0] - vel[2] * r[1], vel[1] + vel[2] * r[0]])
        # target cup: static, upright
        qt = p - ti.Vector([self.target_pose[0], self.target_pose[1]], real)
        for s in ti.static(range(self.n_cup_boxes, len(self.boxes))):
            ps, nl = self._box(qt, s)
            if ps < phi:
                phi = ps
                n = nl
                vc = ti.Vector.zero(real, 2)
        return phi, n, vc

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
        """State slot s -> s + 1 with the cup at its pose of global substep t."""
        real = self.real
        dx = ti.static(self.dx)
        inv_dx = ti.static(1.0 / self.dx)
        dt = ti.static(self.dt)
        # 1. particle to grid: one task per environment, particles in a fixed order (deterministic)
        ti.loop_config(block_dim=1)
        for b in range(self.B):
            for p in range(self.n_part[b]):
                Xp = self.x[s, b, p] * inv_dx
                base = ti.cast(Xp - 0.5, ti.i32)
                fx = Xp - base
                w = bspline_weights(fx)
                affine = affine_momentum(self.J[s, b, p], self.C[s, b, p], self.p_mass, self.p_vol, self.bulk,
                                         self.sc.viscosity, dt, inv_dx, real, 2)
                mv = self.p_mass * self.v[s, b, p]
                for i, j in ti.static(ti.ndrange(3, 3)):
                    offset = ti.Vector([i, j])
                    dpos = (offset - fx) * dx
                    weight = w[i][0] * w[j][1]
                    self.grid_v_in[b, base[0] + i, base[1] + j] += weight * (mv + affine @ dpos)
                    self.grid_m[b, base[0] + i, base[1] + j] += weight * self.p_mass
        # 2. grid update: momentum to velocity, gravity, colliders
        for b, i, j in self.grid_m:
            m = self.grid_m[b, i, j]
            if m > 0:
                v = self.grid_v_in[b, i, j] / m
                v[1] -= dt * self.gravity
                pos = ti.Vector([i * dx, j * dx], real)
                phi, n, vc = self._closest(b, t, pos)
                if phi < 0:
                    v = separate(v, vc, n, self.sc.friction)
                self.grid_v_out[b, i, j] = v
                if ti.static(self.sc.boundary_density):
                    self.grid_rho[b, i, j] = ghost_mass(m, phi, ti.static(self.sc.ppc * self.p_mass))
        # 3. grid to particle, advection, collider projection, position clamp
        ti.loop_config(block_dim=1)
        for b in range(self.B):
            for p in range(self.n_part[b]):
                Xp = self.x[s, b, p] * inv_dx
                base = ti.cast(Xp - 0.5, ti.i32)
                fx = Xp - base
                w = bspline_weights(fx)
                new_v = ti.Vector.zero(real, 2)
                new_C = ti.Matrix.zero(real, 2, 2)
                mass_near = ti.cast(0.0, real)
                for i, j in ti.static(ti.ndrange(3, 3)):
                    dpos = ti.Vector([i, j]) - fx
                    weight = w[i][0] * w[j][1]
                    g_v = self.grid_v_out[b, base[0] + i, base[1] + j]
                    new_v += weight * g_v
                    new_C += 4.0 * inv_dx * weight * g_v.outer_product(dpos)
                    if ti.static(self.sc.volume_correction and self.sc.boundary_density):
                        mass_near += weight * self.grid_rho[b, base[0] + i, base[1] + j]
                    elif ti.static(self.sc.volume_correction):
                        mass_near += weight * self.grid_m[b, base[0] + i, base[1] + j]
                xn = self.x[s, b, p] + dt * new_v
                phi, n, vc = self._closest(b, t, xn)
                if phi < 0:
                    xn -= phi * n
                    new_v = separate(new_v, vc, n, self.sc.friction)
                for d in ti.static(range(2)):
                    xn[d] = ti.math.clamp(xn[d], dx, (self.res[d] - 2) * dx)
                self.x[s + 1, b, p] = xn
                self.v[s + 1, b, p] = new_v
                self.C[s + 1, b, p] = new_C
                # the production solver's J update (shared function: advect, grid-density bound, cap)
                Jn = update_volume_ratio(self.J[s, b, p], new_C.trace(), mass_near, dt,
                                         ti.static(self.sc.ppc * self.p_mass),
                                         ti.static(min(self.sc.dt / self.sc.volume_relax, 1.0)),
                                         self.sc.volume_correction, self.sc.tension,
                                        self.stretch_rate)
                self.J[s + 1, b, p] = Jn

    @ti.func
    def _region_weight(self, pose, r: ti.template(), p):
        """Smooth inside-weight of p for cup region r in the frame of a cup at ``pose``."""
        cs, sn = ti.cos(pose[2]), ti.sin(pose[2])
        d = p - ti.Vector([pose[0], pose[1]])
        q = ti.Vector([cs * d[0] + sn * d[1], -sn * d[0] + cs * d[1]])
        lo, hi = ti.static(self.region_lo[r], self.region_hi[r])
        inv_w = ti.static(1.0 / self.soft_width)
        return (_ramp((q[0] - lo[0]) * inv_w) * _ramp((hi[0] - q[0]) * inv_w)
                * _ramp((q[1] - lo[1]) * inv_w) * _ramp((hi[1] - q[1]) * inv_w))

    @ti.kernel
    def outcome(self, s: ti.i32):
        """Soft fractions of each environment's water inside the controlled and the target cup."""
        ti.loop_config(block_dim=1)
        for b in range(self.B):
            tp = ti.Vector([self.target_pose[0], self.target_pose[1], self.target_pose[2]], self.real)
            inv_n = 1.0 / ti.cast(ti.max(self.n_part[b], 1), self.real)
            for p in range(self.n_part[b]):
                xp = self.x[s, b, p]
                self.soft_ctrl[b] += inv_n * self._region_weight(self.end_pose[b], 0, xp)
                self.soft_tgt[b] += inv_n * self._region_weight(tp, 1, xp)

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

    def run_forward(self, x0: np.ndarray, n_part: np.ndarray, pose: np.ndarray, vel: np.ndarray,
                    end_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Simulate ``pose.shape[1]`` substeps; returns soft in-ctrl, soft in-target (B,) and final x (B, N, 2).

        Leaves the last segment in the buffer and every segment start in the checkpoint field, ready
        for ``run_backward``.
        """
        S = pose.shape[1]
        assert S <= self.T_max
        self._S = S
        cp = np.zeros((self.T_max, self.B, 3), self.np_real)
        cv = np.zeros_like(cp)
        cp[:S] = pose.transpose(1, 0, 2)
        cv[:S] = vel.transpose(1, 0, 2)
        self.cup_pose.from_numpy(cp)
        self.cup_vel.from_numpy(cv)
        self.end_pose.from_numpy(np.asarray(end_pose, self.np_real))
        self.load_state(np.ascontiguousarray(x0, self.np_real), np.asarray(n_part, np.int32))
        segs = self._segments(S)
        last = 0
        for c, (t0, L) in enumerate(segs):
            if c > 0:
                self._copy_slot(last, 0)  # the next segment starts from this one's end state
            self.save_checkpoint(0, c)
            for s in range(L):
                self.clear_grid()
                self.substep(s, t0 + s)
            last = L
        self._last = last
        self.soft_ctrl.fill(0.0)
        self.soft_tgt.fill(0.0)
        self.outcome(last)
        return self.soft_ctrl.to_numpy(), self.soft_tgt.to_numpy(), self._slot_positions(last)

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

    def run_backward(self, d_ctrl: np.ndarray, d_tgt: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Adjoint of the last ``run_forward`` for seeds d objective / d soft_ctrl, d soft_tgt (B,).

        Returns gradients w.r.t. the cup pose and velocity per substep (B, S, 3), the end pose (B, 3)
        and the initial particle positions (B, N, 2).
        """
        S = self._S
        segs = self._segments(S)
        self.cup_pose.grad.fill(0.0)
        self.cup_vel.grad.fill(0.0)
        self.end_pose.grad.fill(0.0)
        self.clear_particle_grads(-1)
        self.soft_ctrl.grad.from_numpy(np.asarray(d_ctrl, self.np_real))
        self.soft_tgt.grad.from_numpy(np.asarray(d_tgt, self.np_real))
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
        g_pose = self.cup_pose.grad.to_numpy()[:S].transpose(1, 0, 2)
        g_vel = self.cup_vel.grad.to_numpy()[:S].transpose(1, 0, 2)
        return g_pose.astype(float), g_vel.astype(float), self.end_pose.grad.to_numpy().astype(float), g_x0.astype(float)
