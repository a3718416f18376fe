"""The MLS-MPM transfers of both solvers, written once: particle to grid, the grid update, grid to particle.

Both solvers keep a grid with a leading environment axis, (B, res...), and call these Taichi functions
with their own fields: the production solver (``sim.engine.mpm``) keeps one particle state per
environment and updates its grid in place; the differentiable one (``sim.engine.diff_mpm``) keeps a
particle state per substep and separate grids in and out (Taichi's reverse mode allows no overwriting).
The physics is ``sim.engine.physics``'s; the colliders are ``sim.engine.colliders``'.

Floats: ``real`` is the solver's type (f32 in production, f64 for gradients). Every line computes in the
order the production solver always has, since its results (the shipped data among them) are these bits;
the constants (dx, dt, the particle mass, ...) are Python floats, which Taichi types as f32 in either
solver. Two forms are the production solver's own and look inconsistent: particle to grid scales
positions by 1 / dx, grid to particle divides by dx (the latter by a constant of the solver's type, so
that the f64 solver's two agree to the last bit).

``factored``: the transfers' per-node affine terms as sums over the offset's digits (``sim.engine.mpm``'s
``_FACTORED_TRANSFERS``: additions instead of matrix products, the same equations rounded differently).
"""

import taichi as ti

from .config import SimConfig
from .physics import affine_momentum, bspline_weights, ghost_mass, separate, update_volume_ratio


@ti.data_oriented
class Stencil:
    """Quadratic B-spline transfers on a (B, res...) grid, and the particle constants of ``cfg``."""

    def __init__(self, cfg: SimConfig, real=ti.f32, factored: bool = False):
        self.cfg, self.real, self.factored = cfg, real, bool(factored)
        self.dim = cfg.dim
        self.p_vol = cfg.dx**cfg.dim / cfg.ppc
        self.p_mass = cfg.rho * self.p_vol
        self.bulk = cfg.rho * cfg.sound_speed**2
        #: per-substep decay of stretch (J > 1); 0 = off (see physics.update_volume_ratio)
        self.stretch_rate = min(cfg.dt / cfg.stretch_relax, 1.0) if cfg.stretch_relax > 0 else 0.0

    @ti.func
    def node(self, b, I):
        """Grid index (b, I) of environment b's node I."""
        r = ti.Vector.zero(ti.i32, self.dim + 1)
        r[0] = b
        for d in ti.static(range(self.dim)):
            r[d + 1] = I[d]
        return r

    @ti.func
    def weight(self, w: ti.template(), offset: ti.template()):
        """The stencil weight of node ``base + offset``: the product of the per-axis weights ``w``."""
        weight = ti.cast(1.0, self.real)
        for d in ti.static(range(self.dim)):
            weight *= w[offset[d]][d]
        return weight

    @ti.func
    def p2g(
        self,
        grid_v: ti.template(),
        grid_m: ti.template(),
        b,
        xp,
        vp,
        Cp,
        Jp,
        serial: ti.template(),
        rows: ti.template(),
        r0,
        r1,
    ):
        """Scatter the mass and momentum of a particle of environment b (position, velocity, affine field,
        volume ratio) to its 3^dim stencil; returns the stencil's first node.

        ``serial``: each node's scatter runs on one thread (plain adds); else atomic adds. ``rows``: only the
        stencil's nodes in grid rows r0 .. r1 - 1 (the production solver's split path)."""
        dx = self.cfg.dx
        inv_dx = 1.0 / dx
        dt = self.cfg.dt
        Xp = xp * inv_dx
        base = ti.cast(Xp - 0.5, ti.i32)
        fx = Xp - base
        w = bspline_weights(fx)
        affine = affine_momentum(
            Jp, Cp, self.p_mass, self.p_vol, self.bulk, self.cfg.viscosity, dt, inv_dx, self.real, self.dim
        )
        mv = self.p_mass * vp
        # factored: mv + affine (offset - fx) dx = c0 + affine offset dx, the second term a sum of the columns
        # of affine dx (offset_d in {0, 1, 2}): additions only, shared between the nodes (unfactored, c0 and
        # a_dx go unused, and the compiler drops them)
        c0 = mv - affine @ (fx * dx)
        a_dx = [ti.Vector([affine[r, d] * dx for r in ti.static(range(self.dim))]) for d in ti.static(range(self.dim))]
        for offset in ti.static(ti.grouped(ti.ndrange(*([3] * self.dim)))):
            weight = self.weight(w, offset)
            mom = mv  # declared here for Taichi's scoping; each branch below sets it
            if ti.static(self.factored):
                mom = c0
                for d in ti.static(range(self.dim)):
                    if ti.static(offset[d] == 1):
                        mom = mom + a_dx[d]
                    elif ti.static(offset[d] == 2):
                        mom = mom + 2.0 * a_dx[d]
            else:
                mom = mv + affine @ ((offset - fx) * dx)
            gi = self.node(b, base + offset)
            if ti.static(serial):  # this node's scatter runs on one thread: plain adds
                if not ti.static(rows) or (r0 <= gi[1] and gi[1] < r1):
                    grid_v[gi] = grid_v[gi] + weight * mom
                    grid_m[gi] = grid_m[gi] + weight * self.p_mass
            else:
                grid_v[gi] += weight * mom
                grid_m[gi] += weight * self.p_mass
        return base

    @ti.func
    def update_node(
        self,
        grid_v: ti.template(),
        grid_m: ti.template(),
        v_out: ti.template(),
        m_out: ti.template(),
        I,
        colliders: ti.template(),
        frames: ti.template(),
        t,
    ):
        """Grid node I = (b, i, j[, k]): momentum to velocity, gravity, the colliders' boundary rule, into
        ``v_out``; with ``sim.boundary_density`` the ghost mass into ``m_out`` (the density estimate's mass).
        ``frames``, ``t``: the bodies' frames (``Colliders.contact``)."""
        m = grid_m[I]
        if m > 0:
            v = grid_v[I] / m
            v[1] -= self.cfg.dt * self.cfg.gravity
            b = I[0]
            pos = ti.Vector.zero(self.real, self.dim)
            for d in ti.static(range(self.dim)):
                pos[d] = I[d + 1] * self.cfg.dx
            phi, idx = colliders.contact(b, pos, frames, t)
            if phi < 0:
                n, vc = colliders.normal_and_velocity(b, idx, pos, frames, t)
                v = separate(v, vc, n, self.cfg.friction)
            if ti.static(self.cfg.boundary_density):  # ghost mass: a solid node reads as water at rest
                m_out[I] = ghost_mass(m, phi, ti.static(self.cfg.ppc * self.p_mass))
            v_out[I] = v

    @ti.func
    def g2p(self, grid_v: ti.template(), grid_m: ti.template(), b, xp):
        """Gather at position xp from environment b's grid: velocity, affine field C and (with
        ``sim.volume_correction``) the grid mass near xp, read from ``grid_m``."""
        dim = ti.static(self.dim)
        dx = ti.static(self.cfg.dx)
        Xp = xp / self.real(dx)
        base = ti.cast(Xp - 0.5, ti.i32)
        fx = Xp - base
        w = bspline_weights(fx)
        new_v = ti.Vector.zero(self.real, dim)
        new_C = ti.Matrix.zero(self.real, dim, dim)
        mass_near = ti.cast(0.0, self.real)
        wgo = ti.Matrix.zero(self.real, dim, dim)  # factored: the sum of weight g_v offset^T
        for offset in ti.static(ti.grouped(ti.ndrange(*([3] * dim)))):
            weight = self.weight(w, offset)
            gi = self.node(b, base + offset)
            g_v = grid_v[gi]
            if ti.static(self.cfg.volume_correction):
                mass_near += weight * grid_m[gi]
            if ti.static(self.factored):
                wg = weight * g_v
                new_v += wg
                for d in ti.static(range(dim)):
                    if ti.static(offset[d] > 0):
                        for r in ti.static(range(dim)):
                            wgo[r, d] += wg[r] if ti.static(offset[d] == 1) else 2.0 * wg[r]
            else:
                new_v += weight * g_v
                new_C += 4.0 / dx * weight * g_v.outer_product(offset - fx)
        if ti.static(self.factored):  # sum of weight g_v (offset - fx)^T, times 4 / dx
            new_C = 4.0 / dx * (wgo - new_v.outer_product(fx))
        return new_v, new_C, mass_near

    @ti.func
    def advect(self, b, xp, new_v, colliders: ti.template(), frames: ti.template(), t):
        """Move a particle from xp with its new velocity over one substep, then out of any collider it ends
        inside (to the surface along the normal, with the boundary rule on its velocity): (x, v)."""
        xn = xp + self.cfg.dt * new_v
        phi, idx = colliders.contact(b, xn, frames, t)
        if phi < 0:
            n, vc = colliders.normal_and_velocity(b, idx, xn, frames, t)
            xn -= phi * n
            new_v = separate(new_v, vc, n, self.cfg.friction)
        return xn, new_v

    @ti.func
    def volume_ratio(self, J, new_C, mass_near):
        """The particle's volume ratio after this substep (``physics.update_volume_ratio``)."""
        return update_volume_ratio(
            J,
            new_C.trace(),
            mass_near,
            self.cfg.dt,
            ti.static(self.cfg.ppc * self.p_mass),
            ti.static(min(self.cfg.dt / self.cfg.volume_relax, 1.0)),
            self.cfg.volume_correction,
            self.cfg.tension,
            self.stretch_rate,
        )

    @ti.func
    def keep_on_grid(self, xn):
        """xn clamped to [dx, (res - 2) dx] per axis, so that its stencil stays on the grid: (x, whether moved)."""
        clamped = False
        for d in ti.static(range(self.dim)):
            lo = self.cfg.dx
            hi = (self.cfg.res[d] - 2) * self.cfg.dx
            if xn[d] < lo or xn[d] > hi:
                clamped = True
                xn[d] = ti.math.clamp(xn[d], lo, hi)
        return xn, clamped
