"""The mean of several learned dynamics models, used as one model (``model.ensemble`` > 1).

Why: a planner searching one model finds the places where that model is wrong and plans through
them (each training seed has its own such places: on the ladder's source rung single models reach
the goal in 0.37-0.53 of the problems). Errors that differ between members shrink in their mean.
The members are ordinary :class:`~dynamics.model.LearnedDynamics`, trained and cached one by one
(:func:`dynamics.config.ensemble_member`); the ensemble itself has no checkpoint of its own.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import torch
from torch import Tensor, nn

from .config import DynamicsError
from .model import LearnedDynamics


class DynamicsEnsemble(nn.Module):
    """f_hat(s, a) = mean over members of f_k(s, a); the same prediction API as LearnedDynamics.

    The mean of valid states is valid: the water fractions of each member are non-negative and sum
    to at most 1, and so is their average.
    """

    dtype = torch.float32
    device = torch.device("cpu")

    def __init__(self, members: Sequence[LearnedDynamics], info: dict | None = None):
        super().__init__()
        if len(members) < 1:
            raise DynamicsError("DynamicsEnsemble needs at least one member")
        self.members = nn.ModuleList(members)
        self.cfg = members[0].cfg
        self.info: dict[str, Any] = dict(info or {})
        self.eval()

    def forward(self, states: Tensor, actions: Tensor) -> Tensor:
        """Differentiable mean prediction [n, 5]."""
        return torch.stack([m(states, actions) for m in self.members]).mean(0)

    def predict(self, states: Tensor, actions: Tensor) -> Tensor:
        """Next states [n, 5] (float32); input checks as :meth:`LearnedDynamics.predict`."""
        return torch.stack([m.predict(states, actions) for m in self.members]).mean(0)

    def predict_np(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Numpy batch path (float64), the members' :meth:`LearnedDynamics.predict_np` averaged."""
        out = self.members[0].predict_np(states, actions)
        for m in self.members[1:]:
            out = out + m.predict_np(states, actions)
        return out / len(self.members)

    def predict_one(self, state: np.ndarray, action: np.ndarray) -> np.ndarray:
        """One transition, numpy in and out (the members' fast path, averaged)."""
        out = self.members[0].predict_one(state, action)
        for m in self.members[1:]:
            out = out + m.predict_one(state, action)
        return out / len(self.members)
