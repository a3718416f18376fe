"""Simulator configuration with validation that runs before any Taichi compute.

Every field has a unit. Errors name the field and the allowed range so that a researcher who typed
a bad override on the Hydra command line learns what to type instead.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, Mapping

ARCHES = ("cpu", "gpu", "auto")
#: the solver's arithmetic: bumped when a change rounds a pour differently with the same configuration (revision 2:
#: the 2D particle-grid transfers run factored, ``sim.engine.mpm._FACTORED_TRANSFERS``). What stores simulated bits
#: keys on it: the source data's hash (``dynamics.config.source_world``) and a run's identity
#: (``active.identity.comparable_config``), so data and runs of another revision are never mixed with this one's.
NUMERICS_REVISION = 2
BOX_NORMALS = ("analytic", "central")


class ConfigError(ValueError):
    """A configuration value is outside its allowed range (the message names field and range)."""


@dataclass
class SimConfig:
    """Weakly compressible MLS-MPM water in a closed rectangular tank.

    The tank spans [0, domain[d]] on every axis; its walls are ``wall_cells`` grid cells thick, so
    water lives in [wall_cells * dx, domain[d] - wall_cells * dx].
    """

    dim: int = 2
    domain: tuple[float, ...] = (0.60, 0.45)  # m, tank size per axis
    dx: float = 0.01  # m, grid spacing
    dt: float = 3.0e-4  # s, substep; must be <= cfl * dx / sound_speed
    rho: float = 1000.0  # kg/m^3, rest density
    sound_speed: float = 12.0  # m/s, numerical speed of sound (bulk modulus = rho c^2)
    gravity: float = 9.81  # m/s^2, acting along -y
    friction: float = 0.0  # Coulomb coefficient water/wall (0 = free slip)
    #: Pa s, dynamic (Newtonian shear) viscosity of the liquid; water is 1e-3 (far below what the grid
    #: resolves: 0 behaves the same), honey 2-10; explicit, so dt must also satisfy dt_visc
    viscosity: float = 0.0
    #: False: no negative pressure (J is capped at 1), so water that separates -- a stream leaving a
    #: lip, a film on a wall -- is not pulled back by tension, as free-surface water should behave;
    #: True: mpm88's p = K (1 - J) on both sides, which makes coarse water cohesive and sticky
    tension: bool = True
    #: True: J never exceeds the grid-density estimate ppc * m_p / sum_i w_ip m_i, so water squeezed by
    #: collider projection (fast-rotating cups) regains its volume instead of staying compressed at
    #: rest pressure; False: J advected only (mpm88), which lets a tilted cup's water collapse into a film
    volume_correction: bool = True
    volume_relax: float = 0.02  # s, time constant of that correction
    #: s, > 0: stretch (J > 1, negative pressure) decays towards J = 1 with this time constant, so
    #: tension holds a stream together but is not stored as history; 0 = off (mpm88)
    stretch_relax: float = 0.0
    #: True: grid nodes inside a wall or collider count as water at rest density in that grid-density
    #: estimate (ghost mass, as SPH's boundary particles), so water piled up against a wall reads as
    #: compressed and is pushed back out; False: solid nodes hold only the mass the water gave them, so the
    #: layers next to walls pack denser than the bulk and keep it (8 cm of water at rest sinks 7 % instead of
    #: 2 %, tests/test_sim_solver.py), and how much packs depends on the water's history
    boundary_density: bool = False
    #: outward normal of a box collider where water is inside it (projection, velocity boundary rule):
    #: "analytic" = the nearest face's (physics.box_sdf; both solvers); "central" = a central difference
    #: of the distance over 0.1 dx, the production solver's earlier rule. They differ near a box's medial
    #: axis (a cup's lip corner): partial pours move by about 0.05, their scatter does not
    box_normals: str = "analytic"
    ppc: int = 4  # particles per cell at rest (must be k**dim)
    n_envs: int = 1  # B, independent environments sharing one set of fields
    max_particles: int = 1024  # per environment
    max_bodies: int = 4  # kinematic rigid bodies per environment
    max_shapes: int = 16  # collider primitives per environment (all bodies)
    wall_cells: int = 3  # tank wall thickness in cells
    cfl: float = 0.5  # stability factor in dt <= cfl * dx / c
    arch: str = "cpu"  # cpu | gpu | auto
    deterministic: bool = True  # CPU: env-serial particle-to-grid transfer (bit reproducible)
    seed: int = 0  # particle jitter seed
    #: initial particles: +- this fraction of the sub-cell spacing of uniform noise around a regular
    #: sub-grid (per environment slot, seeded [seed, env]); 0 = a regular lattice in every slot
    jitter: float = 0.25

    def __post_init__(self) -> None:
        self.domain = tuple(float(v) for v in self.domain)
        self.validate()

    # ------------------------------------------------------------------ validation
    @property
    def dt_max(self) -> float:
        """Acoustic CFL bound: a pressure wave must not cross more than ``cfl`` cells a substep."""
        return self.cfl * self.dx / self.sound_speed

    @property
    def dt_visc(self) -> float:
        """Viscous stability bound of explicit diffusion: nu dt / dx^2 <= cfl / (2 dim), nu = mu / rho."""
        return math.inf if self.viscosity == 0 else self.cfl * self.rho * self.dx**2 / (2 * self.dim * self.viscosity)

    @property
    def res(self) -> tuple[int, ...]:
        """Grid nodes per axis."""
        return tuple(int(round(L / self.dx)) for L in self.domain)

    @property
    def wall(self) -> float:
        """Distance of the tank walls from the domain edge, in metres."""
        return self.wall_cells * self.dx

    def validate(self) -> None:
        def need(cond: bool, name: str, allowed: str) -> None:
            if not cond:
                raise ConfigError(f"sim.{name} = {getattr(self, name)!r} is invalid: allowed {allowed}")

        need(self.dim in (2, 3), "dim", "2 or 3")
        need(0.0 <= self.jitter <= 0.5, "jitter", "[0, 0.5] (fraction of the particle spacing)")
        need(len(self.domain) == self.dim, "domain", f"a list of {self.dim} positive lengths in m")
        need(all(v > 0 and math.isfinite(v) for v in self.domain), "domain", "positive finite lengths in m")
        for name in ("dx", "dt", "rho", "sound_speed", "cfl"):
            need(getattr(self, name) > 0 and math.isfinite(getattr(self, name)), name, "> 0")
        need(self.gravity >= 0, "gravity", ">= 0 m/s^2 (acts along -y)")
        need(0.0 <= self.friction <= 10.0, "friction", "[0, 10]")
        need(0.0 <= self.stretch_relax < math.inf, "stretch_relax", "a finite time >= 0 s (0 = off)")
        need(0.0 <= self.viscosity < math.inf, "viscosity", "a finite value >= 0 Pa s (water 1e-3, honey 2-10)")
        need(self.cfl <= 1.0, "cfl", "(0, 1]")
        k = round(self.ppc ** (1.0 / self.dim))
        need(
            self.ppc >= 1 and k**self.dim == self.ppc, "ppc", f"a perfect power k**{self.dim} (e.g. 1, 4, 9, 16 in 2D)"
        )
        for name in ("n_envs", "max_particles", "max_bodies", "max_shapes"):
            need(isinstance(getattr(self, name), int) and getattr(self, name) >= 1, name, "an integer >= 1")
        need(isinstance(self.wall_cells, int) and self.wall_cells >= 2, "wall_cells", "an integer >= 2")
        need(self.arch in ARCHES, "arch", f"one of {ARCHES}")
        need(self.box_normals in BOX_NORMALS, "box_normals", f"one of {BOX_NORMALS}")
        res = self.res
        need(
            all(r >= 2 * self.wall_cells + 4 for r in res),
            "dx",
            f"small enough for >= {2 * self.wall_cells + 4} cells per axis (domain {self.domain})",
        )
        if self.dt > self.dt_max * (1 + 1e-9):
            raise ConfigError(
                f"sim.dt = {self.dt:g} s is above the stable bound for this grid and stiffness: allowed "
                f"(0, {self.dt_max:.3g}] s = cfl * dx / sound_speed = {self.cfl} * {self.dx} / {self.sound_speed}"
            )
        if self.dt > self.dt_visc * (1 + 1e-9):
            raise ConfigError(
                f"sim.dt = {self.dt:g} s is above the viscous stability bound: allowed (0, {self.dt_visc:.3g}] s = "
                f"cfl * rho * dx^2 / (2 * dim * viscosity); lower sim.viscosity below "
                f"{self.cfl * self.rho * self.dx**2 / (2 * self.dim * self.dt):.3g} Pa s or sim.dt"
            )

    # ------------------------------------------------------------------ (de)serialisation
    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None = None, **overrides: Any) -> "SimConfig":
        """Build from a dict / OmegaConf node; unknown keys are an error listing the known ones."""
        data = dict(cfg or {})
        data.update(overrides)
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown sim config key(s) {unknown}; known keys: {sorted(known)}")
        if "domain" in data:
            data["domain"] = tuple(data["domain"])
        return cls(**data)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["domain"] = list(self.domain)
        return d
