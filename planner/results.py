"""Result containers of the planner: plain numpy, no OMPL objects (nothing to leak or pickle)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .interfaces import describe_action, features


@dataclass(frozen=True)
class Trajectory:
    """A planned trajectory: T actions, T+1 predicted states, and the MDE output per step.

    ``states[0]`` is the start; ``states[t + 1] = f_hat(states[t], actions[t])``;
    ``mu[t], sigma[t]`` are the MDE mean / std for ``(states[t], actions[t])``.
    """

    actions: np.ndarray  # [T, 3]
    states: np.ndarray  # [T + 1, 5]
    mu: np.ndarray  # [T]
    sigma: np.ndarray  # [T]

    def __post_init__(self) -> None:
        for k in ("actions", "states", "mu", "sigma"):
            a = np.array(getattr(self, k), dtype=float)
            a.setflags(write=False)
            object.__setattr__(self, k, a)
        T = len(self.actions)
        if self.states.shape != (T + 1, 5) or self.mu.shape != (T,) or self.sigma.shape != (T,):
            raise ValueError(
                "inconsistent trajectory shapes: "
                f"actions {self.actions.shape}, states {self.states.shape}, "
                f"mu {self.mu.shape}, sigma {self.sigma.shape}"
            )

    def __len__(self) -> int:
        return len(self.actions)

    def __reduce__(self):
        # rebuilt through __init__: unpickled arrays (e.g. from a planner worker process) would
        # otherwise come back writable
        return (type(self), (self.actions, self.states, self.mu, self.sigma))

    @property
    def features(self) -> np.ndarray:
        """MDE features of the T steps, [T, 8]."""
        return features(self.states[:-1], self.actions)

    @property
    def final_state(self) -> np.ndarray:
        return self.states[-1]

    def same_as(self, other: "Trajectory", atol: float = 1e-12) -> bool:
        return (
            len(self) == len(other)
            and np.allclose(self.actions, other.actions, atol=atol, rtol=0)
            and np.allclose(self.states, other.states, atol=atol, rtol=0)
        )

    def describe(self) -> str:
        return " -> ".join(describe_action(a) for a in self.actions) or "(no actions)"


@dataclass(frozen=True)
class PlannerStats:
    """What one RRT run did.

    ``propagations``: (state, action) pairs run through the dynamics model (counted per batch
    row, so it includes proposals that were rejected or never used); ``mde_evaluations``: the
    subset also run through the MDE (those not already excluded by cheap checks: dead states,
    bounds, a last step that misses the goal); ``rejected``: MDE-evaluated pairs that failed
    the precondition;
    ``expansions``: OMPL propagator calls (tree-extension attempts); ``tree_size``: tree nodes
    including the start; ``termination``: "solved", "trivial" (start already satisfies the goal),
    "accepted" (no state within ``goal_tol`` was reached, the plan ends in the wider ``accept_tol`` band),
    "propagation_budget", "time_budget", "exhausted" (no node can be expanded any more) or
    "unreachable" (the start is a dead state: spill above the limit, too much water in the
    target cup or too little left; only with ``prune_dead_states``) or "error" (the run raised and
    the caller asked for failures to be recorded, :meth:`planner.PlanPool.run`; ``error`` says why);
    ``seed``: the 32-bit seed of this run's numpy Generator (derived from the caller's seed);
    ``best_goal_distance``: smallest goal distance over the tree (0 when found).
    """

    found: bool
    time_s: float
    propagations: int
    mde_evaluations: int
    expansions: int
    rejected: int
    tree_size: int
    termination: str
    seed: int
    best_goal_distance: float
    error: str = ""

    @classmethod
    def unexpanded(
        cls,
        termination: str,
        seed: int,
        best_goal_distance: float,
        time_s: float = 0.0,
        tree_size: int = 1,
        error: str = "",
    ) -> "PlannerStats":
        """A run that expanded nothing ("trivial", "unreachable", "error"): found only when trivial, all counts 0."""
        return cls(
            found=termination == "trivial",
            time_s=time_s,
            propagations=0,
            mde_evaluations=0,
            expansions=0,
            rejected=0,
            tree_size=tree_size,
            termination=termination,
            seed=seed,
            best_goal_distance=best_goal_distance,
            error=error,
        )

    @property
    def propagations_per_s(self) -> float:
        return self.propagations / self.time_s if self.time_s > 0 else float("nan")


@dataclass(frozen=True)
class PlanResult:
    """Outcome of one RRT run: the trajectory (``None`` when not found) and statistics."""

    trajectory: Trajectory | None
    stats: PlannerStats

    @property
    def found(self) -> bool:
        return self.trajectory is not None


@dataclass(frozen=True)
class CandidateSet:
    """N candidate trajectories for one problem (distinct; only runs that reached the goal).

    ``runs`` keeps every run's :class:`PlanResult`, found or not, for statistics.
    """

    candidates: list[Trajectory]
    runs: list[PlanResult] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.candidates)

    @property
    def found(self) -> bool:
        return len(self.candidates) > 0

    @property
    def time_s(self) -> float:
        return float(sum(r.stats.time_s for r in self.runs))

    @property
    def propagations(self) -> int:
        return int(sum(r.stats.propagations for r in self.runs))
