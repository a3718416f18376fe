"""Open-loop rollout of an action sequence through the dynamics model and the MDE.

The Random Actions baseline (6 actions from :class:`~planner.sampling.ActionSampler`) needs the
same predicted states and per-step (mu, sigma) as a planned candidate so that the active
learning code can treat both alike; this function gives it a :class:`~planner.results.Trajectory`
computed exactly as the planner computes its tree (same dtype handling, same state clipping).
"""

from __future__ import annotations

import numpy as np

from task.threads import torch_threads

from .config import PlannerConfig
from .interfaces import ACTION_DIM, DeviationEstimator, DynamicsModel
from .problems import validate_start
from .results import Trajectory
from .rrt import _Evaluator
from .sampling import ActionSampler


def rollout(
    dynamics: DynamicsModel, mde: DeviationEstimator | None, start, actions, config: PlannerConfig | None = None
) -> Trajectory:
    """Predict states for ``actions`` [T, 3] from ``start`` and the MDE output for every step.

    No precondition or goal check is applied (a baseline executes whatever it sampled).
    With ``mde=None``, mu and sigma are zero.
    """
    config = config or PlannerConfig()
    s = validate_start(start, config)
    a = np.array(actions, dtype=float).reshape(-1, ACTION_DIM)
    ev = _Evaluator(dynamics, mde, ActionSampler(config))
    states = [s]
    lo, hi = np.asarray(config.state_low), np.asarray(config.state_high)
    with torch_threads(config.torch_threads):
        for t in range(len(a)):
            nxt = ev.predict_next(states[-1][None], a[t : t + 1])[0]
            states.append(np.clip(nxt, lo, hi) if config.clip_to_bounds else nxt)
        S = np.array(states)
        mu, sd = ev.deviation(S[:-1], a) if len(a) else (np.zeros(0), np.zeros(0))
    return Trajectory(actions=a, states=S, mu=mu, sigma=sd)
