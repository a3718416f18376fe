"""Kinematic motion of bodies: smooth profiles and a velocity-level path follower.

Bodies are driven at the velocity level (the solver integrates poses every substep), so a moving
wall carries its velocity into the water's boundary condition. The follower re-reads the pose at
every control step, so integration error never accumulates.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np


def cos_sin(angles: np.ndarray, portable: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of an array of angles; ``portable``: through libm one value at a time.

    Why: numpy's vectorised sin / cos round differently on AVX2 and AVX-512 CPUs (and between
    releases); the simulator's cup schedules must come out the same bits on every machine, so they
    take the scalar path. Callers on a hot path that need no such guarantee (the planner) keep numpy's.
    """
    a = np.asarray(angles, float)
    if not portable:
        return np.cos(a), np.sin(a)
    flat = a.ravel().tolist()
    return (
        np.fromiter(map(math.cos, flat), float, len(flat)).reshape(a.shape),
        np.fromiter(map(math.sin, flat), float, len(flat)).reshape(a.shape),
    )


def min_jerk(tau: np.ndarray | float) -> np.ndarray:
    """Minimum-jerk blend 0 -> 1 on tau in [0, 1] (zero velocity and acceleration at both ends)."""
    t = np.clip(tau, 0.0, 1.0)
    return t * t * t * (10 - 15 * t + 6 * (t * t))  # products, not powers: numpy's vectorised pow varies by CPU


#: peak of d(min_jerk)/dtau: a min-jerk move of length D in time T peaks at this * D / T.
MIN_JERK_PEAK = 1.875


def min_jerk_duration(distance: np.ndarray | float, peak_speed: float, min_time: float = 0.0) -> np.ndarray:
    """Shortest duration of a min-jerk move whose peak speed stays at or below ``peak_speed``."""
    return np.maximum(MIN_JERK_PEAK * np.asarray(distance, float) / peak_speed, min_time)


def follow(
    solver,
    body: int,
    pose_at: Callable[[float], np.ndarray],
    duration: float,
    control_dt: float = 0.01,
    on_control: Callable[[float], None] | None = None,
) -> None:
    """Drive ``body`` in every environment along ``pose_at(t) -> (B, 3)`` for ``duration`` seconds.

    Each control step sets the body velocity that reaches the next target pose exactly (linear and
    angular), then runs the substeps; afterwards the body is brought to rest.
    """
    dt = solver.cfg.dt
    n_sub = max(1, int(round(control_dt / dt)))
    h = n_sub * dt
    n_ctrl = int(np.ceil(duration / h - 1e-9))
    for k in range(n_ctrl):
        t_next = min((k + 1) * h, duration)
        current = solver.body_poses(body)
        target = np.asarray(pose_at(t_next), np.float64)
        vel = (target - current) / h
        solver.set_body_velocity(body, vel[:, :2], vel[:, 2])
        solver.step(n_sub)
        if on_control is not None:
            on_control(t_next)
    solver.set_body_velocity(body, np.zeros((solver.B, 2)), np.zeros(solver.B))
