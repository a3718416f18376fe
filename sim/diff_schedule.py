"""The pour skill's cup trajectory as a smooth function of (x, y, theta, hold), with its Jacobian.

Why: gradients of a rollout outcome reach the skill parameters only through the cup's pose and
velocity at every substep, so the kinematic schedule must be differentiable. This module evaluates
the SAME schedule as ``sim.skills.plan_schedule`` for a single ``pour(theta, hold)`` from an upright
start pose (x, y, 0) -- min-jerk tilt about the pouring lip (``CupConfig.lip``) with duration
``min_jerk_duration(theta, peak_rate, min_time=control_dt)``, hold, min-jerk return, settle -- and the
same velocity-level control as ``sim.execute.PouringExecutor`` (every control tick the cup gets the
constant velocity that reaches the next tick pose, integrated once per substep).

One difference, on purpose: the production schedule lives on the control grid, so its hold lasts
``round(hold / control_dt)`` ticks and starts at the first tick after the tilt ends, a piecewise
constant function of (theta, hold). Here the tilt angle is the continuous-time function

    phi(t) = theta * (min_jerk(t / T) - min_jerk((t - T - hold) / T)),   T = T(theta),

sampled at the control ticks (equal to production wherever T and hold are whole ticks; otherwise the
return starts up to 1.5 ticks = 0.015 s earlier than in production). That makes every tick pose a
smooth (C2) function of theta and hold; its derivative is analytic (below). The horizon (number of
substeps) is NOT a function of the parameters: it is chosen per call and held fixed, so a gradient
is the sensitivity of the outcome at a fixed time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .engine.motion import MIN_JERK_PEAK, min_jerk, min_jerk_duration
from .world import WorldConfig

#: column order of the (B, 4) parameter arrays of the differentiable pour
PARAMS = ("x", "y", "theta", "hold")


def min_jerk_rate(tau: np.ndarray) -> np.ndarray:
    """d min_jerk / d tau (zero outside [0, 1], where ``min_jerk`` is clipped)."""
    t = np.asarray(tau, float)
    inside = (t > 0.0) & (t < 1.0)
    return np.where(inside, 30.0 * t**2 * (1.0 - t) ** 2, 0.0)


def tilt_duration(cfg: WorldConfig, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tilt (and return) duration T(theta) as in ``plan_schedule`` and dT/dtheta."""
    h = cfg.control_dt
    rate = cfg.skills["pour"]["peak_rate"]
    T = min_jerk_duration(np.asarray(theta, float), rate, min_time=h)
    dT = np.where(MIN_JERK_PEAK * np.asarray(theta, float) / rate > h, MIN_JERK_PEAK / rate, 0.0)
    return T, dT


def production_ticks(cfg: WorldConfig, theta: np.ndarray, hold: np.ndarray) -> np.ndarray:
    """Control ticks of the production pour (tilt, hold, return, settle) for each (theta, hold)."""
    h = cfg.control_dt
    T, _ = tilt_duration(cfg, theta)
    n = np.ceil(T / h).astype(int)
    return 2 * n + np.round(np.asarray(hold, float) / h).astype(int) + int(round(cfg.skills["settle"] / h))


def substeps_per_tick(cfg: WorldConfig) -> int:
    return max(1, int(round(cfg.control_dt / float(cfg.sim["dt"]))))


@dataclass
class CupTrajectory:
    """Per-substep cup pose and velocity for B pours, and the tick poses they derive from."""

    pose: np.ndarray  # (B, S, 3): x, y, theta of the cup during substep s (after that substep's update)
    vel: np.ndarray  # (B, S, 3): vx, vy, omega during substep s
    ticks_pose: np.ndarray  # (B, K + 1, 3): poses at the control ticks
    ticks_jac: np.ndarray  # (B, K + 1, 3, 4): d tick pose / d (x, y, theta, hold)
    n_sub: int

    @property
    def substeps(self) -> int:
        return self.pose.shape[1]


def tick_poses(cfg: WorldConfig, params: np.ndarray, ticks: int) -> tuple[np.ndarray, np.ndarray]:
    """Cup poses at control ticks 0..ticks (B, ticks + 1, 3) and their Jacobian (B, ticks + 1, 3, 4)."""
    p = np.asarray(params, float).reshape(-1, 4)
    h = cfg.control_dt
    lx, ly = cfg.controlled_cup.lip
    x, y, theta, hold = (p[:, i : i + 1] for i in range(4))  # (B, 1) each
    T, dT = tilt_duration(cfg, theta)
    t = np.arange(ticks + 1)[None, :] * h  # (1, K + 1)
    u1 = t / T
    u2 = (t - hold) / T - 1.0
    phi = theta * (min_jerk(u1) - min_jerk(u2))
    r1, r2 = min_jerk_rate(u1), min_jerk_rate(u2)
    dphi_dtheta = (min_jerk(u1) - min_jerk(u2)) + theta * (r1 * (-t / T**2) - r2 * (-(t - hold) / T**2)) * dT
    dphi_dhold = theta * r2 / T
    c, s = np.cos(phi), np.sin(phi)
    # origin = pivot - R(phi) lip, pivot = start + lip (upright start)
    ox = x + lx - (c * lx - s * ly)
    oy = y + ly - (s * lx + c * ly)
    dox_dphi = s * lx + c * ly
    doy_dphi = -c * lx + s * ly
    B, K1 = p.shape[0], ticks + 1
    pose = np.stack([ox, oy, phi], -1)
    J = np.zeros((B, K1, 3, 4))
    J[:, :, 0, 0] = 1.0
    J[:, :, 1, 1] = 1.0
    for j, dphi in ((2, dphi_dtheta), (3, dphi_dhold)):
        J[:, :, 0, j] = dox_dphi * dphi
        J[:, :, 1, j] = doy_dphi * dphi
        J[:, :, 2, j] = dphi
    return pose, J


def _frac(n_sub: int) -> np.ndarray:
    return (np.arange(n_sub) + 1.0) / n_sub


def cup_trajectory(cfg: WorldConfig, params: np.ndarray, ticks: int) -> CupTrajectory:
    """Substep-level pose/velocity the executor's velocity control produces from the tick poses.

    During tick k the cup moves with the constant velocity (P[k+1] - P[k]) / h (h = n_sub * dt);
    the solver integrates the pose at the start of each substep, so substep j of tick k sees
    P[k] + (j + 1) / n_sub * (P[k+1] - P[k]).
    """
    P, J = tick_poses(cfg, params, ticks)
    n_sub = substeps_per_tick(cfg)
    h = n_sub * float(cfg.sim["dt"])
    dP = P[:, 1:] - P[:, :-1]  # (B, K, 3)
    B = P.shape[0]
    pose = (P[:, :-1, None] + _frac(n_sub)[None, None, :, None] * dP[:, :, None]).reshape(B, ticks * n_sub, 3)
    vel = np.repeat(dP / h, n_sub, axis=1)
    return CupTrajectory(pose=pose, vel=vel, ticks_pose=P, ticks_jac=J, n_sub=n_sub)


def chain_to_params(cfg: WorldConfig, traj: CupTrajectory, g_pose: np.ndarray, g_vel: np.ndarray) -> np.ndarray:
    """(B, 4) gradient w.r.t. ``PARAMS`` from gradients w.r.t. the per-substep pose and velocity (B, S, 3).

    The substep pose/velocity are linear in the tick poses, so the gradient is first reduced onto
    the ticks (25x smaller at the default resolution) and then multiplied by the tick Jacobian.
    """
    B, S, _ = g_pose.shape
    n_sub = traj.n_sub
    K = S // n_sub
    h = n_sub * float(cfg.sim["dt"])
    gp = g_pose.reshape(B, K, n_sub, 3)
    gv = g_vel.reshape(B, K, n_sub, 3).sum(2) / h  # d/d(dP)
    f = _frac(n_sub)[None, None, :, None]
    g_dP = (gp * f).sum(2) + gv  # gradient w.r.t. dP[k] = P[k+1] - P[k]
    gP = np.zeros((B, K + 1, 3))
    gP[:, :-1] += gp.sum(2) - g_dP
    gP[:, 1:] += g_dP
    return np.einsum("bki,bkij->bj", gP, traj.ticks_jac)


def horizon_ticks(cfg: WorldConfig, params: np.ndarray, horizon: float | None) -> int:
    """Ticks simulated: ``horizon`` seconds, or by default the longest production pour of the batch."""
    p = np.asarray(params, float).reshape(-1, 4)
    if horizon is None:
        return int(production_ticks(cfg, p[:, 2], p[:, 3]).max())
    return max(1, int(math.ceil(horizon / cfg.control_dt - 1e-9)))
