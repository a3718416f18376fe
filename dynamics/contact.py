"""The learned model plus the known static geometry: moves and pours that the source world's
obstacles (target cup, tank walls) would stop are predicted stopped there.

Why: contacts with fixed, known obstacles are rare in the source-world training data, so the MLP
predicts that every move arrives; in the experiment most failed plans were cups stuck on the
target cup's rim. The obstacles are the same in both worlds, so using their geometry is no
target-world knowledge; the plant is not among them and stays the deviation the MDE learns.
A stopped move keeps the MLP's water prediction for the commanded move (water barely moves when
the cup stops); a stopped pour ends at the pose where it touched (tilted), which the planner
treats as a dead state.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor

from sim.contact import ContactPredictor
from sim.world import WorldConfig


class ContactAwareDynamics:
    """Wraps a dynamics model (``predict``, ``predict_np``, ``predict_one``) with :class:`ContactPredictor`."""

    def __init__(self, model: Any, world_cfg: WorldConfig | dict, **contact_kwargs: Any):
        if not isinstance(world_cfg, WorldConfig):
            world_cfg = WorldConfig.from_mapping(world_cfg)
        self.model = model
        self.contacts = ContactPredictor(world_cfg, world="source", **contact_kwargs)

    def _apply(self, s: np.ndarray, a: np.ndarray, out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``out`` with the poses of stuck rows replaced by their stop poses, and which rows are stuck."""
        stuck, stop, _ = self.contacts.first_contact(s[:, :3], a)
        if stuck.any():
            out = out.copy()
            out[stuck, :3] = stop[stuck]
        return out, stuck

    def predict(self, states: Tensor, actions: Tensor) -> Tensor:
        """As the wrapped model's ``predict`` (torch [n, 5], [n, 3] -> [n, 5]), contacts applied."""
        out = self.model.predict(states, actions)
        s = torch.as_tensor(states).detach().double().cpu().numpy()
        a = torch.as_tensor(actions).detach().double().cpu().numpy()
        fixed, _ = self._apply(s, a, out.detach().double().cpu().numpy())
        return torch.as_tensor(fixed, dtype=out.dtype, device=out.device)

    def predict_np(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        s, a = np.asarray(states, float), np.asarray(actions, float)
        if s.ndim == 1:
            return self.predict_one(s, a)
        return self.predict_np_contacts(s, a)[0]

    def predict_np_contacts(self, states: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`predict_np` for [n, 5] states and [n, 3] actions, and which rows are stuck ([n] bool).

        A stuck action ends the trajectory in the simulator, so a planner must not extend a plan from
        it. Its pose alone cannot say so: a move stopped within millimetres of its target looks
        arrived."""
        s, a = np.asarray(states, float), np.asarray(actions, float)
        inner = getattr(self.model, "predict_np", None)
        if inner is None:  # a model with the torch path only
            out = self.model.predict(torch.as_tensor(s, dtype=torch.float32), torch.as_tensor(a, dtype=torch.float32))
            return self._apply(s, a, out.detach().double().cpu().numpy())
        return self._apply(s, a, np.asarray(inner(s, a), float))

    def predict_one(self, state: np.ndarray, action: np.ndarray) -> np.ndarray:
        s, a = np.asarray(state, float).reshape(1, -1), np.asarray(action, float).reshape(1, -1)
        one = getattr(self.model, "predict_one", None)
        out = one(s[0], a[0])[None] if one is not None else self.model.predict_np(s, a)
        return self._apply(s, a, np.asarray(out, float))[0][0]

    def __getattr__(self, name: str) -> Any:  # info, save, cfg, ... of the wrapped model
        # only called for names not found normally; during unpickling ``model`` is not set yet, and
        # forwarding it (or a dunder such as __setstate__) would recurse without end
        if name == "model" or (name.startswith("__") and name.endswith("__")):
            raise AttributeError(name)
        return getattr(self.model, name)
