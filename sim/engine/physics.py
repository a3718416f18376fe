"""The MLS-MPM water model as Taichi functions, shared by the production and differentiable solvers.

One home for what both solvers must agree on (their storage layouts differ: the production solver
keeps one state per environment, the differentiable one a state per substep): the quadratic B-spline
weights, the Cauchy stress of the weakly compressible Newtonian fluid and its MLS-MPM force term,
the update of the volume ratio J, the collider contact rule, the ghost mass of solid grid nodes and
the signed distance of a box. Functions are generic in the float type (f32 in production, f64 for
gradients).

Stress: sigma = -p I + mu (grad v + grad v^T), with p = K (1 - J) (K = rho c^2, mpm88's equation of
state) and the APIC affine matrix C as the velocity gradient. The viscous term is the Newtonian
shear stress of a liquid of dynamic viscosity mu (Pa s); mu = 0 is the inviscid fluid of mpm88.
"""

import taichi as ti

#: floor under a squared length before its square root: the adjoint stays finite at length 0
_TINY = 1e-30


@ti.func
def bspline_weights(fx):
    """Quadratic B-spline weights per axis for fractional offsets fx = x / dx - base (each in [0.5, 1.5))."""
    return [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]


@ti.func
def affine_momentum(
    J, C, p_mass, p_vol, bulk, viscosity: ti.template(), dt, inv_dx, real: ti.template(), dim: ti.template()
):
    """MLS-MPM's affine term of the particle-to-grid transfer: -dt V_p M^-1 sigma + m_p C.

    M^-1 = 4 / dx^2 for quadratic B-splines. The pressure part is written exactly as mpm88 does
    (a scalar on the identity), so the inviscid fluid keeps its bits; ``viscosity`` is a Python
    constant (compile time), so mu = 0 adds no work.
    """
    stress = -dt * 4.0 * bulk * p_vol * (J - 1.0) * inv_dx * inv_dx
    affine = ti.Matrix.identity(real, dim) * stress + p_mass * C
    if ti.static(viscosity > 0):
        affine -= (dt * 4.0 * p_vol * viscosity * inv_dx * inv_dx) * (C + C.transpose())
    return affine


@ti.func
def update_volume_ratio(
    J,
    trace_C,
    mass_near,
    dt,
    rest_mass,
    relax_rate: ti.template(),
    volume_correction: ti.template(),
    tension: ti.template(),
    stretch_rate: ti.template(),
):
    """Advect J with the velocity divergence, then (optionally) the two corrections, in this order.

    ``volume_correction``: J relaxes at ``relax_rate`` (= min(dt / volume_relax, 1)) towards the
    grid-density estimate J_rho = rest_mass / mass_near, bounded below by 0.9, whenever the grid says
    the water is *more* compressed than J does (particles pushed together by collider projection);
    never the other way (free surfaces and walls read low density). ``stretch_rate`` > 0
    (= min(dt / stretch_relax, 1)): stretch (J > 1, negative pressure) decays towards J = 1, so tension
    acts on short time scales (a coherent stream) but is not stored as history. ``tension`` False:
    J <= 1, no negative pressure at all.
    """
    Jn = J * (1.0 + dt * trace_C)
    if ti.static(volume_correction):
        J_rho = ti.max(rest_mass / ti.max(mass_near, 1e-12), 0.9)
        Jn += ti.min(J_rho - Jn, 0.0) * relax_rate
    if ti.static(stretch_rate > 0):
        Jn -= ti.max(Jn - 1.0, 0.0) * stretch_rate
    if ti.static(not tension):
        Jn = ti.min(Jn, 1.0)
    return Jn


@ti.func
def ghost_mass(m, phi, rest_node_mass):
    """Grid-node mass for the density estimate with ``sim.boundary_density``: a node inside a collider
    (phi < 0) counts as at least water at rest, so water next to a wall does not read as
    half-empty and pack into dense wall layers."""
    return ti.select(phi < 0, ti.max(m, rest_node_mass), m)


@ti.func
def separate(v, vc, n, friction: ti.template()):
    """Contact with a collider moving at vc (outward unit normal n): remove inflow, keep outflow.

    The relative velocity loses its inflowing normal part; with ``friction`` > 0 (a compile-time
    constant; 0 = free slip) Coulomb friction slows the tangential slip. A slip under 1e-10 m/s has
    no direction to oppose and is left as it is; the floor under the square root keeps the adjoint
    finite when the slip is exactly 0.
    """
    vr = v - vc
    vn = vr.dot(n)
    if vn < 0:
        vt = vr - vn * n
        if ti.static(friction > 0):
            vt_norm = ti.sqrt(ti.max(vt.dot(vt), _TINY))
            vt *= ti.select(vt_norm > 1e-10, ti.max(0.0, 1.0 + friction * vn / vt_norm), 1.0)
        vr = vt
    return vr + vc


@ti.func
def box_sdf(q, half, real: ti.template()):
    """Signed distance from q to the box |q_d| <= half_d (2D), and the analytic outward normal there.

    Branches rather than the branch-free |max(a, 0)| + min(max_d a_d, 0) so that the outside
    distance can floor its square-root argument (finite adjoint on the surface); the distance is the
    same bits wherever |max(a, 0)|^2 >= 1e-30 (inside sqrt(0) + x = x, outside x + 0 = x). Both
    solvers use this normal (``sim.box_normals = "analytic"``). The production solver's earlier rule,
    a central difference of the distance over 0.1 dx (``"central"``), differs near a box's medial axis
    (a cup's lip corner) and moves partial pours by 0.05; in the f64 solver it also makes rollouts
    non-smooth at the finite-difference scale (BENCHMARKS.md, differentiable pours).
    """
    a = ti.abs(q) - half
    sx = 1.0 if q[0] >= 0 else -1.0
    sy = 1.0 if q[1] >= 0 else -1.0
    phi = ti.cast(0.0, real)
    n = ti.Vector.zero(real, 2)
    if a[0] > 0 or a[1] > 0:
        out = ti.max(a, 0.0)
        phi = ti.sqrt(ti.max(out.dot(out), _TINY))
        n = ti.Vector([sx * out[0], sy * out[1]]) / phi
    elif a[0] > a[1]:
        phi = a[0]
        n = ti.Vector([sx, 0.0], real)
    else:
        phi = a[1]
        n = ti.Vector([0.0, sy], real)
    return phi, n
