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
from .model import MOVE, POUR, LearnedDynamics, check_np_inputs, np_forward


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
        self._np: tuple[list, list[dict] | None] | None = None  # (members' weight lists, stacked weights)
        self.eval()

    def forward(self, states: Tensor, actions: Tensor) -> Tensor:
        """Differentiable mean prediction [n, 5]."""
        return torch.stack([m(states, actions) for m in self.members]).mean(0)

    def predict(self, states: Tensor, actions: Tensor) -> Tensor:
        """Next states [n, 5] (float32); input checks as :meth:`LearnedDynamics.predict`."""
        return torch.stack([m.predict(states, actions) for m in self.members]).mean(0)

    def predict_np(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Numpy batch path (float64): the members' :meth:`LearnedDynamics.predict_np` averaged.

        The members' weights are stacked once, so a batch costs one feature computation and one
        matmul per layer for all members (the planner's batches are small, and per-call overhead
        dominates them)."""
        stacked = self._stacked()
        if stacked is None:  # members of different geometry or activation: one at a time
            out = self.members[0].predict_np(states, actions)
            for m in self.members[1:]:
                out = out + m.predict_np(states, actions)
            return out / len(self.members)
        s, a, skill, single = check_np_inputs(states, actions)
        act = self.members[0].cfg.activation
        out = np.empty_like(s)
        for k in (MOVE, POUR):
            m = skill == k
            if m.all():
                out = np_forward(stacked[k], k, s, a[:, 1:3], act).mean(0)
            elif m.any():
                out[m] = np_forward(stacked[k], k, s[m], a[m, 1:3], act).mean(0)
        return out[0] if single else out

    def _stacked(self) -> list[dict] | None:
        """Per skill, the members' numpy weights stacked on a leading member axis (None if they cannot be).

        Rebuilt whenever a member's own numpy copy was rebuilt (after training or loading weights)."""
        own = [m._weights() for m in self.members]
        if self._np is not None and len(self._np[0]) == len(own) and all(x is y for x, y in zip(self._np[0], own)):
            return self._np[1]
        stacked: list[dict] | None = []
        acts = {m.cfg.activation for m in self.members}
        for k in (MOVE, POUR):
            ws = [w[k] for w in own]
            same = len(acts) == 1 and all(
                w["geom"] == ws[0]["geom"]
                and len(w["W"]) == len(ws[0]["W"])
                and all(x.shape == y.shape for x, y in zip(w["W"], ws[0]["W"]))
                for w in ws
            )
            if not same:
                stacked = None
                break
            stacked.append(
                {
                    **ws[0],
                    "W": [np.stack([w["W"][i] for w in ws]) for i in range(len(ws[0]["W"]))],
                    "b": [np.stack([w["b"][i] for w in ws])[:, None, :] for i in range(len(ws[0]["b"]))],
                    "pose_scale": np.stack([w["pose_scale"] for w in ws])[:, None, :],
                }
            )
        self._np = (own, stacked)
        return stacked

    def invalidate_cache(self) -> None:
        """Forget every numpy copy of the weights (call after changing members' parameters in place)."""
        for m in self.members:
            m.invalidate_cache()
        self._np = None

    def load_state_dict(self, *args: Any, **kwargs: Any) -> Any:  # noqa: D102 - keeps derived copies in sync
        out = super().load_state_dict(*args, **kwargs)
        for m in self.members:
            for net in m.nets:
                net.refresh_geometry()
        self.invalidate_cache()
        return out

    def predict_one(self, state: np.ndarray, action: np.ndarray) -> np.ndarray:
        """One transition, numpy in and out (the members' fast path, averaged)."""
        out = self.members[0].predict_one(state, action)
        for m in self.members[1:]:
            out = out + m.predict_one(state, action)
        return out / len(self.members)
