"""Kinematic colliders of B environments: the tank walls and rigid bodies made of signed-distance primitives.

One store and one query for both solvers. Every environment's shapes are kept in their bodies' frames, and
every body's pose and velocity, on fields with a leading environment axis (``pack_env`` checks a scene's
bodies and lays them out, ``write`` loads them, ``push`` sets the bodies' poses and velocities). The query
(``contact``: the collider a point is deepest inside; ``normal_and_velocity``: its outward normal and
velocity there) reads each body's frame through a ``frames`` object with the Taichi functions
``origin(b, t, k)``, ``rotation(b, t, k)`` (cos, sin) and ``velocity(b, t, k)`` (linear, angular): the
``Colliders`` itself, whose bodies the production solver moves every substep, or the differentiable
solver, which reads its driven bodies' poses at substep t from its inputs. Types: the geometry and the
stored poses are f32; a query computes in the type of its point (f32 in production, f64 for gradients).

Contact rule (``sim.engine.mpm`` docstring): only phi < 0 is acted on (projection, the velocity rule,
ghost mass), so only colliders that can contain a point are evaluated; box normals are analytic
(``physics.box_sdf``) or, with ``sim.box_normals = "central"``, a central difference of the distance.
"""

import math
from typing import Sequence

import numpy as np
import taichi as ti

from .config import ConfigError, SimConfig
from .motion import cos_sin
from .physics import box_sdf
from .scene import SHAPE_KINDS, Body

#: closest-feature index of the tank walls: WALL - 2 * axis - side (shapes have indices >= 0)
WALL = -1
#: m added to every collider's culling bounds, so that float32 rounding never culls a point inside a collider
CULL_MARGIN = 1e-3


@ti.func
def rotate(v, cs):
    """v rotated by the angle whose (cos, sin) is cs: a frame's vector in its parent frame."""
    return ti.Vector([cs[0] * v[0] - cs[1] * v[1], cs[1] * v[0] + cs[0] * v[1]])


@ti.func
def to_frame(p, origin, cs):
    """World point p in the frame at ``origin`` rotated by (cos, sin) ``cs``."""
    d = p - origin
    return ti.Vector([cs[0] * d[0] + cs[1] * d[1], -cs[1] * d[0] + cs[0] * d[1]])


@ti.data_oriented
class Colliders:
    """Tank walls and kinematic bodies of B environments (module docstring); fields placed in ``fb``."""

    def __init__(
        self, cfg: SimConfig, n_envs: int, max_bodies: int, max_shapes: int, fb: ti.FieldsBuilder, real=ti.f32
    ):
        self.cfg, self.real = cfg, real
        self.dim = dim = cfg.dim
        self.B, self.NB, self.NS = n_envs, max_bodies, max_shapes
        self.body_pos = ti.Vector.field(dim, ti.f32)
        self.body_vel = ti.Vector.field(dim, ti.f32)
        self.body_rot = ti.field(ti.f32)
        self.body_omega = ti.field(ti.f32)
        self.body_cs = ti.Vector.field(2, ti.f32)  # cos, sin of body_rot
        self.body_radius = ti.field(ti.f32)  # bounding radius about the body origin (culling)
        self.body_first_shape = ti.field(ti.i32)  # shapes of body k: body_first_shape .. + body_nshapes - 1
        self.body_nshapes = ti.field(ti.i32)
        fb.dense(ti.ij, (self.B, self.NB)).place(
            self.body_pos,
            self.body_vel,
            self.body_rot,
            self.body_omega,
            self.body_cs,
            self.body_radius,
            self.body_first_shape,
            self.body_nshapes,
        )
        self.shape_kind = ti.field(ti.i32)
        self.shape_body = ti.field(ti.i32)
        self.shape_c = ti.Vector.field(2, ti.f32)
        self.shape_cs = ti.Vector.field(2, ti.f32)
        self.shape_size = ti.Vector.field(2, ti.f32)
        self.shape_lo = ti.Vector.field(2, ti.f32)  # the shape's bounds in its body's frame (culling)
        self.shape_hi = ti.Vector.field(2, ti.f32)
        fb.dense(ti.ij, (self.B, self.NS)).place(
            self.shape_kind, self.shape_body, self.shape_c, self.shape_cs, self.shape_size, self.shape_lo, self.shape_hi
        )
        #: (first shape, end) of each body when every environment holds the same bodies and the query unrolls its
        #: loop over their shapes at compile time (``fix_layout``); None: the loop reads the counts at run time
        self.fixed_layout: list[tuple[int, int]] | None = None

    # ================================================================== host side
    def empty_layout(self) -> dict[str, np.ndarray]:
        """Arrays for ``write``, no bodies yet (``pack_env`` fills each environment's)."""
        B, NB, NS = self.B, self.NB, self.NS
        return {
            "shape_kind": np.zeros((B, NS), np.int32),
            "shape_body": np.zeros((B, NS), np.int32),
            "shape_c": np.zeros((B, NS, 2), np.float32),
            "shape_cs": np.zeros((B, NS, 2), np.float32),
            "shape_size": np.ones((B, NS, 2), np.float32),
            "shape_lo": np.zeros((B, NS, 2), np.float32),
            "shape_hi": np.zeros((B, NS, 2), np.float32),
            "body_radius": np.zeros((B, NB), np.float32),
            "body_first_shape": np.zeros((B, NB), np.int32),
            "body_nshapes": np.zeros((B, NB), np.int32),
            "state": np.zeros((B, NB, 6), np.float32),
        }

    def pack_env(
        self, out: dict[str, np.ndarray], b: int, bodies: Sequence[Body], placed_later: Sequence[int] = ()
    ) -> None:
        """Lay environment b's bodies out in ``out`` (``empty_layout``): poses at rest, shapes body by body.

        Checks the counts against the capacities and every collider's outline at its pose against the domain
        (ConfigError), except for the bodies ``placed_later`` (indices), whose poses come later."""
        if len(bodies) > self.NB:
            raise ConfigError(f"env {b}: {len(bodies)} bodies > sim.max_bodies = {self.NB}")
        domain = np.asarray(self.cfg.domain)
        s = 0
        for k, body in enumerate(bodies):
            out["state"][b, k, :3] = body.pose
            out["body_first_shape"][b, k], out["body_nshapes"][b, k] = s, len(body.shapes)
            if body.shapes:
                out["body_radius"][b, k] = (
                    max(np.linalg.norm(sh.center) + sh.bounding_radius() for sh in body.shapes) + CULL_MARGIN
                )
            for outline in body.world_outlines() if k not in placed_later else ():
                if (outline.min(0) < -1e-6).any() or (outline.max(0) > domain + 1e-6).any():
                    raise ConfigError(
                        f"env {b}: collider of body {body.name!r} at pose {body.pose} "
                        f"leaves the domain [0, {list(self.cfg.domain)}] m"
                    )
            for sh in body.shapes:
                if s >= self.NS:
                    raise ConfigError(f"env {b}: more than sim.max_shapes = {self.NS} collider shapes")
                out["shape_kind"][b, s] = SHAPE_KINDS[sh.kind]
                out["shape_body"][b, s] = k
                out["shape_c"][b, s] = sh.center
                out["shape_cs"][b, s] = (math.cos(sh.angle), math.sin(sh.angle))
                out["shape_size"][b, s] = sh.size
                out["shape_lo"][b, s], out["shape_hi"][b, s] = sh.body_bounds(CULL_MARGIN)
                s += 1

    def fix_layout(self, layout: dict[str, np.ndarray]) -> None:
        """Unroll the query's loop over each body's shapes at compile time, for ``layout``'s bodies, which must be
        every environment's. Why: Taichi's reverse mode cannot differentiate a loop whose bounds are read at run
        time (the differentiable solver's case); the shapes evaluated, and so the results, are the same."""
        first, count = layout["body_first_shape"], layout["body_nshapes"]
        if (first != first[0]).any() or (count != count[0]).any():
            raise ValueError("fix_layout: the environments hold different bodies")
        self.fixed_layout = [(int(f), int(f + n)) for f, n in zip(first[0], count[0])]

    def write(self, layout: dict[str, np.ndarray]) -> None:
        """Load the shapes of ``layout`` (``pack_env``) and set every body at rest at its pose."""
        for name, arr in layout.items():
            if name != "state":
                getattr(self, name).from_numpy(arr)
        self.push(layout["state"])

    def push(self, state: np.ndarray) -> None:
        """Set every body's pose and velocity: ``state`` (B, NB, 6) = x, y, theta, vx, vy, omega."""
        if self.dim == 2:
            self.body_pos.from_numpy(np.ascontiguousarray(state[..., 0:2]))
            self.body_vel.from_numpy(np.ascontiguousarray(state[..., 3:5]))
        self.body_rot.from_numpy(np.ascontiguousarray(state[..., 2]))
        self.body_omega.from_numpy(np.ascontiguousarray(state[..., 5]))
        c, s = cos_sin(state[..., 2], portable=True)  # float64 through libm: the same bits on every CPU
        self.body_cs.from_numpy(np.stack([c, s], -1).astype(np.float32))

    def pull(self, state: np.ndarray, velocities: bool = True) -> None:
        """Copy the bodies' poses (and velocities) into ``state`` (B, NB, 6), as ``push`` takes it."""
        state[..., 0:2] = self.body_pos.to_numpy()
        state[..., 2] = self.body_rot.to_numpy()
        if velocities:
            state[..., 3:5] = self.body_vel.to_numpy()
            state[..., 5] = self.body_omega.to_numpy()

    # ================================================================== frames of the stored bodies
    @ti.func
    def origin(self, b, t, k):
        """Body k's origin in environment b (``t``: unused here; the differentiable solver's substep)."""
        return self.body_pos[b, k]

    @ti.func
    def rotation(self, b, t, k):
        return self.body_cs[b, k]

    @ti.func
    def velocity(self, b, t, k):
        return self.body_vel[b, k], self.body_omega[b, k]

    @ti.func
    def move(self, b):
        """Move environment b's bodies by their velocities over one substep."""
        for k in range(self.NB):
            self.body_pos[b, k] += self.cfg.dt * self.body_vel[b, k]
            self.body_rot[b, k] += self.cfg.dt * self.body_omega[b, k]
            self.body_cs[b, k] = ti.Vector([ti.cos(self.body_rot[b, k]), ti.sin(self.body_rot[b, k])])

    # ================================================================== query
    @ti.func
    def shape_sdf(self, b, s, q_body):
        """Signed distance of shape s at q_body, a point in its body's frame."""
        q = q_body - self.shape_c[b, s]
        cs = self.shape_cs[b, s]
        q = ti.Vector([cs[0] * q[0] + cs[1] * q[1], -cs[1] * q[0] + cs[0] * q[1]])
        size = self.shape_size[b, s]
        kind = self.shape_kind[b, s]
        phi = ti.cast(0.0, self.real)
        if kind == 0:  # box
            phi, _ = box_sdf(q, size, self.real)  # the normal: normal_and_velocity (sim.box_normals)
        elif kind == 1:  # capsule along local x
            cx = ti.math.clamp(q[0], -size[0], size[0])
            phi = ti.Vector([q[0] - cx, q[1]]).norm() - size[1]
        else:  # ellipse: first-order distance estimate outside, scaled radius inside
            k0 = (q / size).norm()
            if k0 < 1.0:
                phi = (k0 - 1.0) * ti.min(size[0], size[1])
            else:
                k1 = (q / (size * size)).norm()
                phi = k0 * (k0 - 1.0) / k1
        return phi

    @ti.func
    def contact(self, b, p, frames: ti.template(), t):
        """The collider p is deepest inside: (phi < 0, its index; WALL - axis*2 - side for the tank walls),
        or (0, 0) when p is inside none.

        Only colliders that can contain p are evaluated: a body whose bounding circle does not contain p
        is skipped, and so is a shape whose bounds in the body frame do not (circle and bounds contain their
        shapes with a margin, and every shape's distance, the ellipse's estimate included, is negative
        exactly inside it; the tests compare squared norms and coordinates: no square root). The minimum
        over the colliders containing p, scanned in the same order with the same strict test, is the
        minimum over all of them: the same (phi, index) to the bit as the full scan whenever p is inside a
        collider. This query is the production solver's largest cost (``benchmarks.sim_profile``).
        """
        phi = ti.cast(0.0, self.real)
        idx = 0
        for d in ti.static(range(self.dim)):
            lo = p[d] - self.cfg.wall
            hi = (self.cfg.domain[d] - self.cfg.wall) - p[d]
            if lo < phi:
                phi = lo
                idx = WALL - 2 * d
            if hi < phi:
                phi = hi
                idx = WALL - 2 * d - 1
        if ti.static(self.dim == 2):
            for k in ti.static(range(self.NB)):  # shapes are stored body by body (pack_env)
                ns = self.body_nshapes[b, k]
                r = self.body_radius[b, k]
                o = frames.origin(b, t, k)
                if ns > 0 and (p - o).norm_sqr() < r * r:
                    q = to_frame(p, o, frames.rotation(b, t, k))
                    if ti.static(self.fixed_layout):
                        for s in ti.static(range(*self.fixed_layout[k])):
                            phi, idx = self._deeper(b, s, q, phi, idx)
                    else:
                        s0 = self.body_first_shape[b, k]
                        for s in range(s0, s0 + ns):
                            phi, idx = self._deeper(b, s, q, phi, idx)
        return phi, idx

    @ti.func
    def _deeper(self, b, s, q, phi, idx):
        """(shape s's distance at q, s) where q is inside s's bounds and deeper inside s than ``phi``; else
        (phi, idx)."""
        lo, hi = self.shape_lo[b, s], self.shape_hi[b, s]
        if lo[0] < q[0] and q[0] < hi[0] and lo[1] < q[1] and q[1] < hi[1]:
            ps = self.shape_sdf(b, s, q)
            if ps < phi:
                phi = ps
                idx = s
        return phi, idx

    @ti.func
    def normal_and_velocity(self, b, idx, p, frames: ti.template(), t):
        """Outward unit normal and velocity at p of collider ``idx`` (``contact``'s index)."""
        n = ti.Vector.zero(self.real, self.dim)
        vc = ti.Vector.zero(self.real, self.dim)
        if idx < 0:
            w = WALL - idx
            for d in ti.static(range(self.dim)):
                if w // 2 == d:
                    n[d] = 1.0 if w % 2 == 0 else -1.0
        else:
            if ti.static(self.dim == 2):
                k = self.shape_body[b, idx]
                o = frames.origin(b, t, k)
                cs_body = frames.rotation(b, t, k)
                is_box = self.shape_kind[b, idx] == 0
                if ti.static(self.cfg.box_normals == "analytic") and is_box:  # physics.box_sdf's
                    q = to_frame(p, o, cs_body) - self.shape_c[b, idx]
                    cs = self.shape_cs[b, idx]
                    _, nl = box_sdf(
                        ti.Vector([cs[0] * q[0] + cs[1] * q[1], -cs[1] * q[0] + cs[0] * q[1]]),
                        self.shape_size[b, idx],
                        self.real,
                    )
                    n = rotate(rotate(nl, cs), cs_body)  # shape frame -> body -> world
                else:  # capsule, ellipse (and boxes with box_normals=central): central difference over 0.1 dx
                    h = 0.1 * self.cfg.dx
                    for d in ti.static(range(2)):
                        e = ti.Vector.zero(self.real, 2)
                        e[d] = h
                        n[d] = self.shape_sdf(b, idx, to_frame(p + e, o, cs_body)) - self.shape_sdf(
                            b, idx, to_frame(p - e, o, cs_body)
                        )
                    n = n / ti.max(n.norm(), 1e-12)
                r = p - o
                vel, w = frames.velocity(b, t, k)
                vc = vel + ti.Vector([-w * r[1], w * r[0]])
        return n, vc
