"""The pouring task, defined once: state layout, skills, spill, goal test, distance, problems.

A leaf package (numpy and torch only) that the simulator, the planner, the dynamics model and the
loop all read, so that none of them redefines what a state is or when a goal is reached.

State ``s = (x, y, theta, v_ctrl, v_tgt)``: the controlled cup's floor centre (m), its tilt (rad),
and the fractions of the water in the controlled and in the target cup. Action
``a = (skill, p1, p2)``: ``move(x, y)`` or ``pour(theta, hold)``.
"""

from __future__ import annotations

from typing import Mapping, TypeVar

import numpy as np
from torch import Tensor

from .problems import WORLDS, Problem, check_world, on_lattice, sample_problems  # noqa: F401 - re-exported

STATE_DIM = 5
ACTION_DIM = 3
FEATURE_DIM = STATE_DIM + ACTION_DIM
STATE_NAMES = ("x", "y", "theta", "v_ctrl", "v_tgt")
ACTION_NAMES = ("skill", "p1", "p2")
#: names of the MDE's input features ``concat(s, a)``
FEATURE_NAMES = STATE_NAMES + ACTION_NAMES
X, Y, THETA, V_CTRL, V_TGT = range(STATE_DIM)

SKILL_MOVE = 0
SKILL_POUR = 1
SKILL_NAMES = {SKILL_MOVE: "move", SKILL_POUR: "pour"}
#: Names of (p1, p2) per skill, used in error messages and pretty printing.
SKILL_PARAM_NAMES = {SKILL_MOVE: ("x", "y"), SKILL_POUR: ("theta", "hold")}

#: the paper's spill limit: at most 2 % of the water outside both cups
DEFAULT_SPILL_LIMIT = 0.02

ArrayT = TypeVar("ArrayT", np.ndarray, Tensor)


def _as_array(x):
    return x if isinstance(x, (np.ndarray, Tensor)) else np.asarray(x, dtype=float)


def spill(states: ArrayT) -> ArrayT:
    """Fraction of the water in neither cup: ``1 - v_ctrl - v_tgt`` (numpy or torch, any leading dims)."""
    states = _as_array(states)
    return 1.0 - states[..., V_CTRL] - states[..., V_TGT]


def goal_reached(state: ArrayT, goal: float, tolerance: float, max_spill: float = DEFAULT_SPILL_LIMIT):
    """The goal test: ``|v_tgt - goal| <= tolerance`` and ``spill <= max_spill``.

    Vectorised over leading dimensions; returns a bool for a single state.
    """
    state = _as_array(state)
    ok = (abs(state[..., V_TGT] - goal) <= tolerance) & (spill(state) <= max_spill)
    if isinstance(ok, Tensor):
        return bool(ok) if ok.dim() == 0 else ok
    ok = np.asarray(ok)
    return bool(ok) if ok.ndim == 0 else ok


def goal_distance(state: ArrayT, goal: float, tolerance: float, max_spill: float = DEFAULT_SPILL_LIMIT):
    """How far a state is from satisfying :func:`goal_reached` (0 exactly when it does): the sum of
    the two constraint violations (the planner's goal distance)."""
    state = _as_array(state)
    a = abs(state[..., V_TGT] - goal) - tolerance
    b = spill(state) - max_spill
    if isinstance(state, Tensor):
        return a.clamp_min(0.0) + b.clamp_min(0.0)
    return np.maximum(a, 0.0) + np.maximum(b, 0.0)


def state_distance(s_i: np.ndarray, s_j: np.ndarray, weights: Mapping[str, float] | None = None) -> np.ndarray:
    """d(s_i, s_j) = w_pose ||(x, y, theta)_i - (x, y, theta)_j|| + w_volume (|dv_ctrl| + |dv_tgt|):
    the paper's distance (weights 1), the MDE's label and the planner's metric."""
    w = {"pose": 1.0, "volume": 1.0, **(weights or {})}
    a, b = np.asarray(s_i, float), np.asarray(s_j, float)
    pose = np.linalg.norm(a[..., :3] - b[..., :3], axis=-1)
    vol = np.abs(a[..., 3] - b[..., 3]) + np.abs(a[..., 4] - b[..., 4])
    return w["pose"] * pose + w["volume"] * vol
