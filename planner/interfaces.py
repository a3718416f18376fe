"""Shared interfaces between the planner, the dynamics model and the MDE.

The planner only talks to the learned dynamics model and to the model deviation estimator (MDE)
through the two small protocols below, so that ``planner`` depends on neither ``mde`` nor on
wherever the dynamics model lives. Layouts are fixed by the project lead:

- state ``s`` (5): ``(x, y, theta, v_ctrl, v_tgt)`` -- pose of the controlled cup (floor centre,
  metres; theta in radians, 0 = upright, positive = tilted towards the target cup) and the
  fractions of all water inside the controlled cup and inside the target cup;
  ``spill = 1 - v_ctrl - v_tgt``. The layout and the goal test live in the leaf package ``task``.
- action ``a`` (3): ``(skill_id, p1, p2)``; skill 0 = ``move(x, y)``, skill 1 = ``pour(theta, hold)``.
- MDE features ``X = concat(s, a)`` (8).
"""

from __future__ import annotations

from typing import Protocol, TypeVar, runtime_checkable

import numpy as np
import torch
from torch import Tensor

# -- layout constants and the task's tests: one home, the leaf package ``task`` -------------------
from task import (  # noqa: F401 - re-exported: the planner's public names
    ACTION_DIM,
    DEFAULT_SPILL_LIMIT,
    FEATURE_DIM,
    SKILL_MOVE,
    SKILL_NAMES,
    SKILL_PARAM_NAMES,
    SKILL_POUR,
    STATE_DIM,
    STATE_NAMES,
    THETA,
    V_CTRL,
    V_TGT,
    X,
    Y,
    goal_distance,
    goal_reached,
    spill,
)


@runtime_checkable
class DynamicsModel(Protocol):
    """Learned (inaccurate) dynamics model f_hat(s, a) -> s'.

    Batched on purpose: the planner evaluates many candidate actions per tree node in one call.
    """

    def predict(self, states: Tensor, actions: Tensor) -> Tensor:
        """Predict next states, ``states`` [n, 5] and ``actions`` [n, 3] -> [n, 5]."""
        ...


@runtime_checkable
class DeviationEstimator(Protocol):
    """Model deviation estimator: a Gaussian over d(f_hat(s, a), s') given X = concat(s, a)."""

    def predict(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Return ``(mean [n], std [n])`` of the predicted deviation for features ``x`` [n, 8]."""
        ...


ArrayT = TypeVar("ArrayT", np.ndarray, Tensor)


def features(states: ArrayT, actions: ArrayT) -> ArrayT:
    """MDE input features ``concat(s, a)``; works for numpy arrays and torch tensors alike.

    Leading batch dimensions must match; a single state/action pair gives a vector of 8.
    """
    if isinstance(states, Tensor) or isinstance(actions, Tensor):
        s = torch.as_tensor(states)
        a = torch.as_tensor(actions, dtype=s.dtype, device=s.device)
        _check_last_dim(s.shape, a.shape)
        return torch.cat([s, a], dim=-1)
    s = np.asarray(states, dtype=float)
    a = np.asarray(actions, dtype=float)
    _check_last_dim(s.shape, a.shape)
    return np.concatenate([s, a], axis=-1)


def _check_last_dim(s_shape: tuple[int, ...], a_shape: tuple[int, ...]) -> None:
    if len(s_shape) == 0 or s_shape[-1] != STATE_DIM:
        raise ValueError(f"states must have last dimension {STATE_DIM}, got shape {tuple(s_shape)}")
    if len(a_shape) == 0 or a_shape[-1] != ACTION_DIM:
        raise ValueError(f"actions must have last dimension {ACTION_DIM}, got shape {tuple(a_shape)}")
    if tuple(s_shape[:-1]) != tuple(a_shape[:-1]):
        raise ValueError(f"states {tuple(s_shape)} and actions {tuple(a_shape)} batch shapes differ")


def split_features(x: ArrayT) -> tuple[ArrayT, ArrayT]:
    """Inverse of :func:`features`: ``x[..., :5], x[..., 5:]``."""
    return x[..., :STATE_DIM], x[..., STATE_DIM:]


def skill_ids(actions: ArrayT) -> ArrayT:
    """Integer skill id of each action (the first action component, rounded)."""
    if isinstance(actions, Tensor):
        return actions[..., 0].round().long()
    return np.rint(np.asarray(actions)[..., 0]).astype(np.int64)


def describe_action(action) -> str:
    """Human-readable form, e.g. ``move(x=0.210, y=0.150)``."""
    a = np.asarray(action, dtype=float)
    sid = int(round(a[0]))
    name = SKILL_NAMES.get(sid, f"skill{sid}")
    p = SKILL_PARAM_NAMES.get(sid, ("p1", "p2"))
    return f"{name}({p[0]}={a[1]:.3f}, {p[1]}={a[2]:.3f})"
