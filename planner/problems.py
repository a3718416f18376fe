"""Validation of a planning call's input: start state, goal amount and tolerance, precondition.

Validation lives here (not inside the RRT) so that bad input fails before any OMPL object is
built, with a message that names the offending field and its allowed range. The problems
themselves (type and sampler) are the task's: :mod:`task.problems`.
"""

from __future__ import annotations

import math

import numpy as np

from .config import PlannerConfig
from .interfaces import STATE_DIM, STATE_NAMES


def validate_start(start, config: PlannerConfig) -> np.ndarray:
    """Return ``start`` as a float array or raise ``ValueError`` naming the bad field."""
    s = np.asarray(start, dtype=float)
    if s.shape != (STATE_DIM,):
        raise ValueError(f"start must be a state vector of {STATE_DIM} values {STATE_NAMES}, got shape {s.shape}")
    for i, name in enumerate(STATE_NAMES):
        lo, hi = config.state_low[i], config.state_high[i]
        v = float(s[i])
        if not math.isfinite(v) or v < lo or v > hi:
            raise ValueError(f"start state field {name}={v!r} outside allowed range [{lo}, {hi}]")
    return s.copy()


def validate_goal(goal: float, tol: float) -> tuple[float, float]:
    """Goal amount must lie in [0, 1] and the tolerance must be positive."""
    try:
        g, t = float(goal), float(tol)
    except (TypeError, ValueError):
        raise ValueError(f"goal and tol must be numbers, got goal={goal!r}, tol={tol!r}") from None
    if not math.isfinite(g) or not 0.0 <= g <= 1.0:
        raise ValueError(f"goal g={goal!r} outside allowed range [0, 1] (fraction of water in the target cup)")
    if not math.isfinite(t) or t <= 0.0:
        raise ValueError(f"goal tolerance tol={tol!r} must be > 0")
    return g, t


def validate_precondition(beta: float, d_max: float) -> tuple[float, float]:
    try:
        b, d = float(beta), float(d_max)
    except (TypeError, ValueError):
        raise ValueError(f"beta and d_max must be numbers, got beta={beta!r}, d_max={d_max!r}") from None
    if not math.isfinite(b):
        raise ValueError(f"beta={beta!r} must be finite")
    if not math.isfinite(d):
        raise ValueError(f"d_max={d_max!r} must be finite")
    return b, d
