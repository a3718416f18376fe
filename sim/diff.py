"""Differentiable pour outcomes in the source world, and gradient refinement of pour parameters.

Why: a plan's pour(theta, hold) from cup position (x, y) is chosen by a planner with a learned model;
a few gradient steps in the source-world simulator can move its parameters towards the goal amount.
This module differentiates the outcome of a whole pour rollout with Taichi's reverse mode.

What:
* ``DifferentiablePour(world_cfg, n_envs)``: B pours at once. ``forward(params)`` gives a
  ``PourOutcome`` (soft and hard fractions in the target cup / in the controlled cup / spilled);
  ``value_and_grad(params, wrt, objective)`` adds d objective / d parameter for each environment.
  ``params`` is (B, 4) = (x, y, theta, hold): the upright cup's start pose (inner-floor centre) and
  the pour skill's parameters, the same meaning as ``sim.skills.pour`` executed by
  ``sim.execute.PouringExecutor`` from that pose.
* ``refine_pours(...)``: projected Adam steps (normalised parameter space, clipped to the world's
  skill ranges) on (soft_in_target - goal)^2 + spill_weight * soft_spill^2, batched.

Model (see ``sim.engine.diff_mpm`` and ``sim.diff_schedule``): the production physics and constants in a
differentiable solver (f64 by default), built for the source world by :func:`source_solver`, the one place that
turns the world into the solver's geometry; the cup follows the production pour schedule evaluated continuously in
time (so theta and hold enter smoothly); the water starts as production samples it (``sample_water``, seed
[sim.seed, env]) at rest in the upright cup, ``v_ctrl`` of the full fill.
Gradient w.r.t. x and y includes the initial particle positions (they move with the cup).

Outcomes: the soft inside-weight of a particle is a product of C2 ramps, one per side of the cup's
interior box (``WorldConfig.volume_regions``: floor to rim, half a cell of tolerance), each going
from 0 to 1 over +-``soft_width`` (default dx / 2) around the box side. Water resting in a cup is
at least dx / 2 inside the box (the walls keep it there), so the soft fractions equal the hard counts
unless water is near a boundary (crossing the rim, sitting on a wall top) at the final time.
soft_spill = 1 - soft_in_ctrl - soft_in_target.

Limits (measured numbers in the report of issue #8 and ``benchmarks.sim_diff``):
* The gradient is exact for the rollout as simulated (central differences with eps = 1e-7 agree
  to 5+ digits at a 0.6 s horizon, tests/test_sim_diff.py), but that rollout is only piecewise
  smooth: a grid node entering or leaving a collider, or the nearest collider switching, is a jump.
  Differences with eps >= 1e-6 already cross jumps at 0.6 s, and over a whole pour (2+ s) the
  local derivative grows by orders of magnitude (measured d spill / d theta = 137 at 2.2 s while
  differences over 1e-4..1e-7 give -2..225). The hard outcome is a staircase (1 / n_particles per
  step). So a whole-pour gradient is a local, noisy signal, not the slope of the outcome curve.
* The soft outcome has gradient only from particles within ``soft_width`` of a region boundary at
  the final time (zero when every particle has settled); ``soft_width`` > dx / 2 widens that band.
* Forward agreement with production: pours that empty the cup agree within 0.03; partial pours do
  NOT yet (this solver keeps 0.12-0.26 more water in the cup; cause open, not f32 vs f64).
* The horizon (substeps) is fixed per call: by default the longest production pour in the batch
  (tilt + hold + return + settle). Gradients are sensitivities of the outcome at that fixed time.
* The schedule's hold is continuous; production rounds it to control ticks (10 ms), see
  ``sim.diff_schedule``.
* Source world only (no plant), one pour from an upright cup, kinematic cup (no contact check
  during the differentiable rollout; the production schedule's stuck test is reported per env).
* Memory: checkpointing every K substeps keeps O(T / K + K) particle states; a configuration that
  does not fit ``memory_budget`` (default half the available RAM) fails before compute.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import torch
from tqdm.auto import tqdm

from .diff_schedule import PARAMS, chain_to_params, cup_trajectory, horizon_ticks, production_ticks, substeps_per_tick
from .engine.config import ConfigError
from .engine.diff_mpm import DiffMPM
from .engine.scene import Body, EnvSpec, WaterBlock, sample_water
from .skills import Obstacles, cup_boundary, plan_schedule, pour, start_overlap
from .world import CTRL, WorldConfig

log = logging.getLogger(__name__)

#: parameters a gradient can be taken with respect to (columns of ``params``)
DIFFERENTIABLE = frozenset(PARAMS)
PRECISIONS = ("f64", "f32")

#: objective(in_target_soft, spill_soft) -> (value, d value / d in_target, d value / d spill), all (B,)
Objective = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]
OBJECTIVES = ("in_target", "spill")


@dataclass
class PourOutcome:
    """Fractions of each environment's water at the end of the horizon, soft and hard (counts)."""

    in_target_soft: np.ndarray  # (B,)
    in_ctrl_soft: np.ndarray
    spill_soft: np.ndarray
    in_target: np.ndarray  # hard counts / particles, as PouringExecutor's state
    in_ctrl: np.ndarray
    spill: np.ndarray
    stuck: np.ndarray  # (B,) bool: the production schedule of this pour hits an obstacle
    nan: np.ndarray  # (B,) bool: non-finite state or gradient
    horizon: float  # s simulated
    substeps: int
    value: np.ndarray | None = None  # (B,) objective, with value_and_grad
    gradients: dict[str, np.ndarray] = field(default_factory=dict)  # name -> (B,)


@dataclass
class RefineResult:
    """Best iterate per environment, with the history of every step."""

    params: np.ndarray  # (B, 4) refined (best) parameters
    initial_params: np.ndarray
    loss_initial: np.ndarray  # (B,)
    loss_best: np.ndarray
    in_target_best: np.ndarray  # soft in-target fraction at the best iterate
    spill_best: np.ndarray
    failed: np.ndarray  # (B,) bool: went NaN at some step; params kept at the initial values
    history: list[dict] = field(default_factory=list)  # per step: params, loss, in_target, spill, grads
    wall_seconds: float = 0.0


def goal_objective(goals: np.ndarray, spill_weight: float = 1.0) -> Objective:
    """(in_target - goal)^2 + spill_weight * spill^2 per environment."""
    g = np.asarray(goals, float)

    def f(t: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return (t - g) ** 2 + spill_weight * s**2, 2.0 * (t - g), 2.0 * spill_weight * s

    return f


def _named_objective(name: str) -> Objective:
    if name == "in_target":
        return lambda t, s: (t, np.ones_like(t), np.zeros_like(t))
    if name == "spill":
        return lambda t, s: (s, np.zeros_like(s), np.ones_like(s))
    raise ConfigError(
        f"objective = {name!r}: allowed one of {OBJECTIVES} or a callable "
        f"(in_target, spill) -> (value, d_in_target, d_spill)"
    )


def available_memory() -> int:
    """Bytes of RAM available now (MemAvailable; total physical memory where /proc is missing)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def _gib(n: float) -> str:
    return f"{n / 2**30:.2f} GiB"


def source_solver(
    cfg: WorldConfig,
    n_envs: int,
    n_particles: int,
    max_substeps: int,
    checkpoint_every: int,
    precision: str = "f64",
    arch: str = "cpu",
    soft_width: float | None = None,
) -> DiffMPM:
    """The differentiable solver of the source world: the controlled cup (body ``CTRL``) driven per substep, the
    target cup standing at its pose, and the two cups' interiors as the regions (``WorldConfig.volume_regions``:
    the controlled cup's in its frame at the end of the rollout, the target cup's in its own)."""
    bodies = [
        Body("cup", shapes=cfg.controlled_cup.shapes()),
        Body("target", pose=cfg.target_pose(), shapes=cfg.target_cup.shapes()),
    ]
    _, lo, hi = cfg.volume_regions()
    return DiffMPM(
        cfg.sim_config(n_envs),
        bodies,
        n_particles,
        max_substeps,
        checkpoint_every,
        driven=(CTRL,),
        regions=list(zip(lo.tolist(), hi.tolist())),
        precision=precision,
        arch=arch,
        soft_width=soft_width,
    )


class DifferentiablePour:
    """B source-world pours, differentiable w.r.t. (x, y, theta, hold); see the module docstring."""

    def __init__(
        self,
        world_cfg: WorldConfig,
        n_envs: int,
        checkpoint_every: int | None = None,
        max_horizon: float | None = None,
        arch: str = "cpu",
        precision: str = "f64",
        soft_width: float | None = None,
        memory_budget: float | None = None,
    ):
        """Check every size against the memory budget, then allocate (and compile lazily).

        ``max_horizon`` (s) sizes the fields: default the longest production pour within the world's
        skill ranges. ``checkpoint_every`` (substeps): default ceil(sqrt(max substeps)); a value >= the
        horizon means no checkpointing. ``memory_budget`` in bytes (default half the available RAM).
        """
        self.cfg = cfg = world_cfg
        if not isinstance(n_envs, (int, np.integer)) or n_envs < 1:
            raise ConfigError(f"n_envs = {n_envs!r}: allowed an integer >= 1")
        if precision not in PRECISIONS:
            raise ConfigError(f"precision = {precision!r}: allowed one of {PRECISIONS}")
        self.B = int(n_envs)
        self.n_sub = substeps_per_tick(cfg)
        pr = cfg.skills["pour"]
        longest = int(production_ticks(cfg, np.array([pr["theta"][1]]), np.array([pr["hold"][1]]))[0])
        if max_horizon is None:
            self.max_ticks = longest
        else:
            if not (isinstance(max_horizon, (int, float)) and math.isfinite(max_horizon) and max_horizon > 0):
                raise ConfigError(f"max_horizon = {max_horizon!r}: allowed a duration > 0 s")
            self.max_ticks = int(math.ceil(max_horizon / cfg.control_dt - 1e-9))
        self.max_substeps = self.max_ticks * self.n_sub
        K = int(math.ceil(math.sqrt(self.max_substeps))) if checkpoint_every is None else checkpoint_every
        if not isinstance(K, (int, np.integer)) or K < 1:
            raise ConfigError(f"checkpoint_every = {checkpoint_every!r}: allowed an integer >= 1 (substeps)")
        self.K = int(min(K, self.max_substeps))
        sc = cfg.sim_config(1)
        self.dx, self.ppc, self.seed, self.jitter = sc.dx, sc.ppc, sc.seed, sc.jitter
        self._local_water = self._sample_local(1.0)
        self.N = max(len(w) for w in self._local_water)
        self.precision = precision
        budget = 0.5 * available_memory() if memory_budget is None else float(memory_budget)
        self._check_memory(budget, sc.res, sc.boundary_density)
        self.sim = source_solver(
            cfg, self.B, self.N, self.max_substeps, self.K, precision=precision, arch=arch, soft_width=soft_width
        )
        self._boundary = cup_boundary(cfg)
        self._target_pose = np.asarray(cfg.target_pose(), float)
        self.last_timing: dict[str, float] = {}

    # ------------------------------------------------------------------ set-up checks
    def _check_memory(self, budget: float, res: tuple[int, int], boundary_density: bool) -> None:
        """ConfigError naming horizon / checkpoint_every / n_envs when the fields would not fit."""
        B, N, S = self.B, self.N, self.max_substeps

        def need(b: int, s: int, k: int) -> int:
            return DiffMPM.memory_bytes(
                b, N, s, k, res, self.precision, boundary_density=boundary_density, n_driven=1, n_regions=2
            )

        self.memory_estimate = need(B, S, self.K)
        if self.memory_estimate <= budget:
            return
        ks = np.arange(1, S + 1)
        fits = [int(k) for k in ks if need(B, S, int(k)) <= budget]
        head = (
            f"differentiable pour: n_envs = {B}, horizon = {self.max_ticks * self.cfg.control_dt:g} s "
            f"({S} substeps of {N} particles), checkpoint_every = {self.K} need {_gib(self.memory_estimate)} "
            f"> memory_budget {_gib(budget)}"
        )
        if fits:
            raise ConfigError(
                f"{head}; allowed checkpoint_every in [{min(fits)}, {max(fits)}] (e.g. {int(math.ceil(math.sqrt(S)))})"
            )
        best_k = lambda s: max(1, int(round(math.sqrt(s))))  # noqa: E731
        lo, hi = 0, S
        while lo < hi:  # the longest horizon that fits with sqrt checkpointing
            mid = (lo + hi + 1) // 2
            if need(B, mid, best_k(mid)) <= budget:
                lo = mid
            else:
                hi = mid - 1
        s_fit = lo
        b_fit = max((b for b in range(1, B) if need(b, S, best_k(S)) <= budget), default=0)
        raise ConfigError(
            f"{head}, and no checkpoint_every fits (even with checkpointing): allowed horizon "
            f"<= {s_fit / self.n_sub * self.cfg.control_dt:.3g} s for n_envs = {B}, or n_envs <= "
            f"{b_fit} for this horizon (or a larger memory_budget)"
        )

    def _sample_local(self, fill: float) -> list[np.ndarray]:
        """Water of each environment in the cup frame (upright cup at the origin), production sampling."""
        return [self._sample_local_one(b, fill) for b in range(self.B)]

    def check_params(
        self, params: np.ndarray, v_ctrl: np.ndarray | None = None, wrt: Sequence[str] = ()
    ) -> tuple[np.ndarray, np.ndarray]:
        """Validate before compute; returns (params (B, 4) float64, v_ctrl (B,))."""
        bad = [w for w in wrt if w not in DIFFERENTIABLE]
        if isinstance(wrt, str) or bad:
            raise ConfigError(
                f"wrt = {list(wrt) if not isinstance(wrt, str) else wrt!r}: "
                f"{bad or wrt!r} not differentiable; allowed names {sorted(DIFFERENTIABLE)} "
                f"(columns of params: {list(PARAMS)})"
            )
        p = np.asarray(params, float)
        if p.shape != (self.B, 4):
            raise ConfigError(f"params: expected shape ({self.B}, 4) = (n_envs, {list(PARAMS)}), got {p.shape}")
        sk = self.cfg.skills
        ranges = {
            "x": ("skills.move.x", sk["move"]["x"]),
            "y": ("skills.move.y", sk["move"]["y"]),
            "theta": ("skills.pour.theta", sk["pour"]["theta"]),
            "hold": ("skills.pour.hold", sk["pour"]["hold"]),
        }
        for j, name in enumerate(PARAMS):
            key, (lo, hi) = ranges[name]
            col = p[:, j]
            out = ~np.isfinite(col) | (col < lo - 1e-9) | (col > hi + 1e-9)
            if out.any():
                b = int(np.flatnonzero(out)[0])
                raise ConfigError(f"params[{b}, {j}] ({name}) = {col[b]:g} is outside {key} = [{lo:g}, {hi:g}]")
        v = np.ones(self.B) if v_ctrl is None else np.asarray(v_ctrl, float).reshape(-1)
        if v.shape != (self.B,) or not np.all((v > 0) & (v <= 1)):
            raise ConfigError(f"v_ctrl: expected {self.B} fill fractions in (0, 1], got {v_ctrl}")
        obst = self._obstacles()
        for b in range(self.B):
            name = start_overlap(obst, self._boundary, np.array([p[b, 0], p[b, 1], 0.0]))
            if name is not None:
                raise ConfigError(
                    f"params[{b}] (x, y) = ({p[b, 0]:g}, {p[b, 1]:g}): the cup overlaps the {name} "
                    f"there; choose a start pose clear of every obstacle"
                )
        return p, v

    def _obstacles(self) -> Obstacles:
        return Obstacles(
            self.cfg.obstacle_bodies("source"),
            np.full(2, self.cfg.floor),
            np.asarray(self.cfg.sim["domain"], float) - self.cfg.floor,
        )

    def _ticks(self, p: np.ndarray, horizon: float | None) -> int:
        ticks = horizon_ticks(self.cfg, p, horizon)
        if ticks > self.max_ticks:
            raise ConfigError(
                f"horizon = {ticks * self.cfg.control_dt:g} s (needed by these pours) exceeds the "
                f"max_horizon = {self.max_ticks * self.cfg.control_dt:g} s this DifferentiablePour was "
                f"sized for: allowed horizon <= {self.max_ticks * self.cfg.control_dt:g} s "
                f"(build it with a larger max_horizon)"
            )
        return ticks

    def stuck(self, p: np.ndarray) -> np.ndarray:
        """Whether each pour's production schedule runs into the target cup or the tank."""
        obst = self._obstacles()
        return np.array(
            [
                plan_schedule(
                    self.cfg, np.array([p[b, 0], p[b, 1], 0.0]), pour(p[b, 2], p[b, 3])[None], obst, self._boundary
                ).stuck
                for b in range(self.B)
            ]
        )

    # ------------------------------------------------------------------ compute
    def _initial(self, p: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x0 = np.zeros((self.B, self.N, 2))
        n = np.zeros(self.B, np.int32)
        local = self._local_water if np.all(v == 1.0) else None
        for b in range(self.B):
            pts = local[b] if local is not None else self._sample_local_one(b, v[b])
            x0[b, : len(pts)] = pts + p[b, :2]
            n[b] = len(pts)
        return x0, n

    def _sample_local_one(self, b: int, fill: float) -> np.ndarray:
        """Environment b's water, ``fill`` of the full cup, in the cup frame (seed [sim.seed, b], as production)."""
        cc = self.cfg.controlled_cup
        spec = EnvSpec(
            bodies=[Body("cup", shapes=cc.shapes())],
            water=[WaterBlock((-cc.inner_width / 2, 0.0), (cc.inner_width / 2, cc.fill_height * fill), body="cup")],
        )
        return sample_water(spec, self.dx, self.ppc, np.random.default_rng([self.seed, b]), self.jitter).astype(float)

    def _hard(self, x: np.ndarray, n: np.ndarray, end_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hard fractions in the controlled / target cup (``MPMSolver.count_in_regions`` semantics)."""
        _, lo, hi = self.cfg.volume_regions()
        tp = np.asarray(self.cfg.target_pose())
        out = np.zeros((2, self.B))
        for b in range(self.B):
            free = np.ones(n[b], bool)  # a particle counts in the first region that holds it
            for r, pose in enumerate((end_pose[b], tp)):
                c, s = math.cos(pose[2]), math.sin(pose[2])
                d = x[b, : n[b]] - pose[:2]
                q = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1)
                inside = free & np.all((q >= lo[r]) & (q <= hi[r]), axis=1)
                free &= ~inside
                out[r, b] = inside.sum() / max(n[b], 1)
        return out[0], out[1]

    def _run(
        self,
        params: np.ndarray,
        v_ctrl: np.ndarray | None,
        horizon: float | None,
        wrt: Sequence[str],
        objective: str | Objective | None,
    ) -> PourOutcome:
        p, v = self.check_params(params, v_ctrl, wrt)
        if objective is not None and not callable(objective):
            objective = _named_objective(objective)
        ticks = self._ticks(p, horizon)
        t0 = time.perf_counter()
        traj = cup_trajectory(self.cfg, p, ticks)
        end_pose = traj.pose[:, -1]
        x0, n = self._initial(p, v)
        stuck = self.stuck(p)
        t1 = time.perf_counter()
        regions = np.stack([end_pose, np.broadcast_to(self._target_pose, end_pose.shape)], 1)  # volume_regions' order
        soft, x_end = self.sim.run_forward(x0, n, traj.pose[:, :, None], traj.vel[:, :, None], regions)
        t2 = time.perf_counter()
        hard_c, hard_t = self._hard(x_end.astype(float), n, end_pose)
        soft_c, soft_t = soft[:, 0].astype(float), soft[:, 1].astype(float)
        nan = ~np.isfinite(x_end).all(axis=(1, 2)) | ~np.isfinite(soft_c) | ~np.isfinite(soft_t)
        out = PourOutcome(
            in_target_soft=soft_t,
            in_ctrl_soft=soft_c,
            spill_soft=1.0 - soft_c - soft_t,
            in_target=hard_t,
            in_ctrl=hard_c,
            spill=1.0 - hard_c - hard_t,
            stuck=stuck,
            nan=nan,
            horizon=ticks * self.cfg.control_dt,
            substeps=traj.substeps,
        )
        timing = {"setup": t1 - t0, "forward": t2 - t1}
        if objective is not None:
            value, d_t, d_s = (np.asarray(a, float) for a in objective(out.in_target_soft, out.spill_soft))
            out.value = value
            if wrt:
                # spill = 1 - ctrl - target
                g_pose, g_vel, g_regions, g_x0 = self.sim.run_backward(np.stack([-d_s, d_t - d_s], 1))
                t3 = time.perf_counter()
                g_pose, g_vel = g_pose[:, :, 0], g_vel[:, :, 0]
                g_pose[:, -1] += g_regions[:, 0]  # the controlled-cup region moves with the cup's final pose
                g = chain_to_params(self.cfg, traj, g_pose, g_vel)
                g[:, :2] += g_x0.sum(1)  # the water starts in the cup: it moves with (x, y)
                for j, name in enumerate(PARAMS):
                    if name in wrt:
                        out.gradients[name] = g[:, j]
                out.nan |= ~np.isfinite(g).all(1)
                timing["backward"] = t3 - t2
        timing["total"] = time.perf_counter() - t0
        self.last_timing = timing
        return out

    def forward(
        self, params: np.ndarray, v_ctrl: np.ndarray | None = None, horizon: float | None = None
    ) -> PourOutcome:
        """Outcome of B pours (no gradient); ``horizon`` in s, default the longest production pour."""
        return self._run(params, v_ctrl, horizon, (), None)

    def value_and_grad(
        self,
        params: np.ndarray,
        wrt: Sequence[str] = ("theta", "hold"),
        objective: str | Objective = "in_target",
        v_ctrl: np.ndarray | None = None,
        horizon: float | None = None,
    ) -> PourOutcome:
        """Outcome, per-environment objective and its gradient w.r.t. the parameters named in ``wrt``.

        ``objective``: "in_target" (soft fraction in the target cup), "spill", or a callable
        (in_target_soft, spill_soft) -> (value, d value / d in_target, d value / d spill), all (B,).
        """
        return self._run(params, v_ctrl, horizon, tuple(wrt), objective)

    def close(self) -> None:
        self.sim.close()


# ---------------------------------------------------------------------------------- refinement
def _skill_ranges(cfg: WorldConfig) -> tuple[np.ndarray, np.ndarray]:
    sk = cfg.skills
    r = [sk["move"]["x"], sk["move"]["y"], sk["pour"]["theta"], sk["pour"]["hold"]]
    return np.array([a for a, _ in r], float), np.array([b for _, b in r], float)


def _refine_arguments(
    params: np.ndarray, goals: np.ndarray, steps: int, lr: float, spill_weight: float
) -> tuple[np.ndarray, np.ndarray]:
    """``refine_pours``' arguments checked before compute: (params (B, 4), goals (B,))."""
    p0 = np.asarray(params, float)
    B = p0.shape[0] if p0.ndim == 2 else -1
    g = np.asarray(goals, float).reshape(-1)
    if p0.ndim != 2 or p0.shape[1] != 4:
        raise ConfigError(f"params: expected shape (B, 4) = (B, {list(PARAMS)}), got {p0.shape}")
    if g.shape != (B,) or not np.all((g >= 0) & (g <= 1)):
        raise ConfigError(f"goals: expected {B} fractions in [0, 1], got {goals}")
    if not (isinstance(steps, (int, np.integer)) and steps >= 1):
        raise ConfigError(f"steps = {steps!r}: allowed an integer >= 1")
    if not (lr > 0 and math.isfinite(lr)):
        raise ConfigError(f"lr = {lr!r}: allowed > 0 (normalised units: fraction of each parameter's range)")
    if not (spill_weight >= 0 and math.isfinite(spill_weight)):
        raise ConfigError(f"spill_weight = {spill_weight!r}: allowed >= 0")
    return p0, g


def refine_pours(
    world_cfg: WorldConfig,
    params: np.ndarray,
    goals: np.ndarray,
    v_ctrl: np.ndarray | None = None,
    steps: int = 10,
    lr: float = 0.05,
    wrt: Sequence[str] = ("theta", "hold"),
    spill_weight: float = 1.0,
    horizon: float | None = None,
    progress: bool = True,
    pour_sim: DifferentiablePour | None = None,
    **sim_kwargs,
) -> RefineResult:
    """Refine B pours towards their goal amounts by projected Adam steps in the source world.

    Minimises (soft_in_target - goal)^2 + spill_weight * soft_spill^2 per environment over the
    parameters in ``wrt`` (the others stay fixed), in coordinates normalised to the world's skill
    ranges ([0, 1] per parameter; ``lr`` is in those units) and clipped to them after every step.
    Keeps each environment's best evaluated iterate (a pour whose production schedule gets stuck is
    never "best"). An environment that goes NaN is recorded in ``failed`` and keeps its initial
    parameters; the others continue. ``pour_sim`` reuses a compiled ``DifferentiablePour``. With
    ``horizon=None`` each step simulates the longest production pour of the batch at the current
    parameters (shorter pours in the batch get extra settling time). Production rounds the refined
    hold to 10 ms ticks.
    """
    t_start = time.perf_counter()
    p0, g = _refine_arguments(params, goals, steps, lr, spill_weight)
    B = len(p0)
    sim = pour_sim if pour_sim is not None else DifferentiablePour(world_cfg, B, **sim_kwargs)
    if sim.B != B:
        raise ConfigError(f"pour_sim has n_envs = {sim.B}, params has {B} rows")
    p0, v = sim.check_params(p0, v_ctrl, tuple(wrt))  # errors before compute
    lo, hi = _skill_ranges(world_cfg)
    span = np.where(hi > lo, hi - lo, 1.0)
    cols = [PARAMS.index(w) for w in wrt]
    objective = goal_objective(g, spill_weight)
    u = torch.tensor(np.clip((p0 - lo) / span, 0.0, 1.0))  # normalised parameters (float64), stepped by Adam
    opt = torch.optim.Adam([u], lr=lr, betas=(0.9, 0.999), eps=1e-8)
    best_p, best_loss = p0.copy(), np.full(B, np.inf)
    best_t, best_s = np.full(B, np.nan), np.full(B, np.nan)
    loss0 = np.full(B, np.nan)
    failed = np.zeros(B, bool)
    history: list[dict] = []
    it = range(steps + 1)  # the last evaluation scores the final step (no update after it)
    if progress:
        it = tqdm(it, desc=f"refine {B} pours", unit="step")
    for k in it:
        p = lo + u.numpy() * span
        p[failed] = p0[failed]
        out = sim.value_and_grad(p, wrt=tuple(wrt), objective=objective, v_ctrl=v, horizon=horizon)
        grad = np.zeros_like(u)
        for j, name in zip(cols, wrt):
            grad[:, j] = out.gradients[name] * span[j]
        bad = out.nan | ~np.isfinite(out.value) | ~np.isfinite(grad).all(1)
        for b in np.flatnonzero(bad & ~failed):
            log.warning(
                "refine_pours: env %d went NaN at step %d (params %s); its initial parameters stay", b, k, p[b].tolist()
            )
        failed |= bad
        if k == 0:
            loss0 = np.where(failed, np.nan, out.value)
        ok = ~failed & ~out.stuck & (out.value < best_loss)
        best_loss[ok], best_p[ok] = out.value[ok], p[ok]
        best_t[ok], best_s[ok] = out.in_target_soft[ok], out.spill_soft[ok]
        history.append(_history_row(k, p, out, grad, failed))
        if progress:
            it.set_postfix(loss=f"{np.nanmean(np.where(failed, np.nan, out.value)):.4f}")
        if k < steps:  # the last evaluation only scores the final step
            grad[failed] = 0.0
            u.grad = torch.from_numpy(grad)
            opt.step()
            u.clamp_(0.0, 1.0)  # projected onto the skill ranges
    best_p[failed] = p0[failed]
    if pour_sim is None:
        sim.close()
    return RefineResult(best_p, p0, loss0, best_loss, best_t, best_s, failed, history, time.perf_counter() - t_start)


def _history_row(k: int, p: np.ndarray, out: Any, grad: np.ndarray, failed: np.ndarray) -> dict:
    """Step ``k``'s record in :attr:`RefineResult.history` (copies: the arrays change at the next step)."""
    return {
        "step": k,
        "params": p.copy(),
        "loss": out.value.copy(),
        "in_target": out.in_target_soft.copy(),
        "in_target_hard": out.in_target.copy(),
        "spill": out.spill_soft.copy(),
        "grad": grad.copy(),
        "stuck": out.stuck.copy(),
        "failed": failed.copy(),
    }


# ---------------------------------------------------------------------------------- CLI
def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        prog="python -m sim.diff", description="Outcome and gradient of one source-world pour."
    )
    ap.add_argument("--x", type=float, default=0.31)
    ap.add_argument("--y", type=float, default=0.14)
    ap.add_argument("--theta", type=float, default=1.5)
    ap.add_argument("--hold", type=float, default=0.5)
    ap.add_argument("--checkpoint-every", type=int, default=None)
    ap.add_argument("--arch", default="cpu")
    args = ap.parse_args(argv)
    cfg = WorldConfig.load()
    dp = DifferentiablePour(cfg, 1, checkpoint_every=args.checkpoint_every, arch=args.arch)
    out = dp.value_and_grad(np.array([[args.x, args.y, args.theta, args.hold]]), wrt=PARAMS)
    print(
        f"in_target soft {out.in_target_soft[0]:.4f} hard {out.in_target[0]:.4f}; spill soft {out.spill_soft[0]:.4f} "
        f"hard {out.spill[0]:.4f}; horizon {out.horizon:g} s ({out.substeps} substeps)"
    )
    print("d in_target_soft / d " + ", ".join(f"{k} = {v[0]:+.4g}" for k, v in out.gradients.items()))
    print("timing " + ", ".join(f"{k} {v:.2f} s" for k, v in dp.last_timing.items()))


if __name__ == "__main__":
    main()
