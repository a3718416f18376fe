"""The random action sampler shared by the RRT and the Random Actions baseline.

The paper's Random Actions baseline "samples a trajectory of length 6 using the action sampler
the planner uses", so the planner draws every proposed action through this class; baselines
must use it too (``ActionSampler(config).sample(6, rng)``).
"""

from __future__ import annotations

import numpy as np

from task import on_lattice

from .config import PlannerConfig
from .interfaces import ACTION_DIM, SKILL_MOVE, SKILL_POUR


class ActionSampler:
    """Uniform skill choice (``p_move`` for move) and uniform parameters within the config ranges.

    All randomness comes from the caller's ``numpy.random.Generator`` so results are seeded and
    reproducible; the sampler itself holds no state.
    """

    def __init__(self, config: PlannerConfig | None = None) -> None:
        self.config = config or PlannerConfig()
        c = self.config
        self._lo = np.array([[c.move_x[0], c.move_y[0]], [c.pour_theta[0], c.pour_hold[0]]])
        self._span = np.array(
            [
                [c.move_x[1] - c.move_x[0], c.move_y[1] - c.move_y[0]],
                [c.pour_theta[1] - c.pour_theta[0], c.pour_hold[1] - c.pour_hold[0]],
            ]
        )

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` actions as a float array [n, 3] of ``(skill_id, p1, p2)``."""
        n = int(n)
        if n < 0:
            raise ValueError(f"n={n} must be >= 0")
        u = rng.random((n, ACTION_DIM))
        skill = np.where(u[:, 0] < self.config.p_move, SKILL_MOVE, SKILL_POUR)
        out = np.empty((n, ACTION_DIM))
        out[:, 0] = skill
        out[:, 1:] = self._lo[skill] + u[:, 1:] * self._span[skill]
        lat = self.config.move_lattice
        if lat:  # where the world puts the cup: the nearest lattice point inside the move range
            move = skill == SKILL_MOVE
            lo, hi = self._lo[0], self._lo[0] + self._span[0]
            lo_lat = np.maximum(np.ceil(lo / lat - 1e-9) * lat, lo)  # max / min: float rounding of k * lat
            hi_lat = np.minimum(np.floor(hi / lat + 1e-9) * lat, hi)
            out[move, 1:] = np.clip(on_lattice(out[move, 1:], lat), lo_lat, hi_lat)
        return out

    def contains(self, actions: np.ndarray) -> np.ndarray:
        """Whether each action is a known skill with parameters inside the configured ranges."""
        a = np.atleast_2d(np.asarray(actions, dtype=float))
        sid = a[:, 0]
        ok = np.isin(sid, (SKILL_MOVE, SKILL_POUR))
        idx = np.where(sid == SKILL_POUR, 1, 0)
        lo = self._lo[idx]
        hi = lo + self._span[idx]
        ok &= np.all((a[:, 1:] >= lo) & (a[:, 1:] <= hi), axis=1)
        return ok
