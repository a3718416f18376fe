"""The data-collection methods: how one training trajectory is chosen for a problem.

* ``random_actions``: a fixed number of actions from the planner's action sampler (no planning);
* ``random_plan``: a uniformly random candidate among the planner's candidates that reach the goal;
* ``active_cautious`` / ``active_mean`` / ``active_balanced``: the candidate that maximises the
  acquisition function (the paper's alpha with c = -0.1 / 0 / 0.1).

If the planner finds no candidate, a method falls back to random actions and the trajectory is
marked ``fallback`` (recorded in categories.csv), so every iteration still collects data.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
import torch

#: method name -> c of the paper's acquisition (None: the method does not use an acquisition)
METHODS: dict[str, float | None] = {
    "random_actions": None,
    "random_plan": None,
    "active_cautious": -0.1,
    "active_mean": 0.0,
    "active_balanced": 0.1,
}


def check_method(name: str) -> str:
    if name not in METHODS:
        raise ValueError(f"method = {name!r}: allowed one of {sorted(METHODS)}")
    return name


@dataclass
class Choice:
    actions: np.ndarray  # (T, 3)
    source: str  # "plan", "random_actions" or "fallback"
    n_candidates: int
    scores: list[float] | None = None
    chosen: int | None = None


def choose(method: str, candidates: list, rng: np.random.Generator, random_actions: Callable[[], np.ndarray],
           make_acquisition: Callable[[float], Any] | None = None) -> Choice:
    """Pick the trajectory to execute from the planner's candidates (each has ``.features`` [T, d]
    and ``.actions`` [T, 3])."""
    check_method(method)
    if method == "random_actions":
        return Choice(random_actions(), "random_actions", 0)
    if not candidates:
        return Choice(random_actions(), "fallback", 0)
    if method == "random_plan":
        k = int(rng.integers(len(candidates)))
        return Choice(np.asarray(candidates[k].actions), "plan", len(candidates), chosen=k)
    acq = make_acquisition(METHODS[method])
    scores = []
    with torch.no_grad():
        for cand in candidates:  # candidates differ in length: one q-batch each
            X = torch.as_tensor(np.asarray(cand.features), dtype=torch.float64).unsqueeze(0)
            scores.append(float(acq(X).item()))
    k = int(np.argmax(scores))  # BoTorch convention: acquisitions are maximised
    return Choice(np.asarray(candidates[k].actions), "plan", len(candidates), scores=scores, chosen=k)
