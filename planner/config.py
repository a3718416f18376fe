"""Planner configuration: bounds, action ranges, budgets.

The dataclass defaults are the library's (tests, stand-in benchmarks). A run of ``python -m active.run``
gets its values from ``configs/planner/default.yaml``: the planner-only keys there mirror these defaults
(a test keeps them in sync) and the keys the task or the protocol fixes (action ranges, plan length,
goal band, spill limit, d_max, candidates, budgets) are interpolated from ``world`` and ``experiment``,
so each is set in one place (``active.loop.build_planner_config`` checks that they agree). The
dataclasses do not read the YAML themselves because ``configs/`` is not shipped inside the installed
package.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields
from typing import Any, Mapping

from task import STATE_NAMES

Range = tuple[float, float]


def _range(name: str, r: Any, lo_limit: float | None = None, hi_limit: float | None = None) -> Range:
    try:
        lo, hi = (float(v) for v in r)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (low, high), got {r!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
        raise ValueError(f"{name} must be a finite range with low <= high, got ({lo}, {hi})")
    if lo_limit is not None and lo < lo_limit:
        raise ValueError(f"{name} low end {lo} is below {lo_limit}")
    if hi_limit is not None and hi > hi_limit:
        raise ValueError(f"{name} high end {hi} is above {hi_limit}")
    return (lo, hi)


@dataclass(frozen=True)
class PlannerConfig:
    """All planner settings (defaults = the design brief / paper protocol).

    Budgets are per candidate (one RRT run). ``propagation_budget`` counts (state, action) pairs
    evaluated by the dynamics model and the MDE (including those evaluated in a batch and later
    rejected), which makes it the deterministic budget; ``time_budget`` is a wall-clock safety net.
    """

    # state bounds: x, y, theta, v_ctrl, v_tgt
    state_low: tuple[float, float, float, float, float] = (0.05, 0.03, 0.0, 0.0, 0.0)
    state_high: tuple[float, float, float, float, float] = (0.55, 0.35, 2.4, 1.0, 1.0)
    # action parameter ranges
    move_x: Range = (0.05, 0.55)
    move_y: Range = (0.03, 0.35)
    pour_theta: Range = (0.0, 2.4)
    pour_hold: Range = (0.0, 1.5)
    #: move targets on a lattice of this spacing (m), as the world executes them (``world.skills.lattice``);
    #: 0 = continuous targets
    move_lattice: float = 0.0
    #: probability that the action sampler picks ``move`` (otherwise ``pour``)
    p_move: float = 0.5
    max_actions: int = 6
    goal_tol: float = 0.05
    #: None: a plan must end within ``goal_tol`` of the goal. A band wider than ``goal_tol`` (the world's
    #: tolerance when ``goal_tol`` aims at the band's middle): the search still stops at the first state
    #: within ``goal_tol``, but when the budget runs out without one, the plan to the tree state closest to
    #: the goal within ``accept_tol`` is returned (the plan the wide band would have found, more centred)
    accept_tol: float | None = None
    spill_limit: float = 0.02
    #: precondition mu + beta * sigma < d_max; defaults are the paper's test-time values,
    #: every planning call may override them (the experiment passes beta, d_max, n and seed per call,
    #: so ``beta`` and ``seed`` are no settings of a run)
    beta: float = 2.0
    d_max: float = 0.07
    n_candidates: int = 9
    time_budget: float = 1.0
    propagation_budget: int = 20000
    seed: int = 0
    #: RRT goal bias (fraction of tree-growth targets drawn from the goal region)
    goal_bias: float = 0.05
    #: first / largest number of actions evaluated in one batch for one tree node
    batch_min: int = 16
    batch_max: int = 256
    #: at most this many actions are tried from a node one step below the depth limit (only
    #: goal-reaching transitions are admissible there)
    last_step_proposals: int = 32
    #: weights of the planner's nearest-neighbour metric: |(x,y)|, |theta|, |v_ctrl|, |v_tgt|
    distance_weights: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    #: clip predicted states into the state bounds (a regression model can leave them slightly,
    #: e.g. theta = -1e-3 after a pour); if False such transitions are rejected instead
    clip_to_bounds: bool = True
    #: keep predicted states that can no longer reach the goal out of the tree (spill above the
    #: limit, too much water in the target cup, too little water left); see rrt._Search._dead
    prune_dead_states: bool = True
    #: a predicted tilt above this (rad) after an action means the cup got stuck mid-pour: in the
    #: simulator such a trajectory ends there, so the state is dead too (part of the pruning)
    stuck_tilt: float = 0.05
    #: a move whose predicted end position is farther than this (m) from its commanded target got
    #: stuck on the way (the simulator ends the trajectory there): pruned like a dead state
    stuck_move: float = 0.005
    #: torch intra-op threads while planning (restored afterwards; :func:`task.threads.torch_threads`);
    #: 0 leaves torch alone. 1 is fastest for the small batches the planner evaluates and avoids
    #: thread-pool stalls on busy 2-core machines
    torch_threads: int = 1
    #: OMPL log level while planning: "none", "error", "warn", "info", "debug"
    ompl_log_level: str = "error"

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731  (frozen dataclass)
        lo = tuple(float(v) for v in self.state_low)
        hi = tuple(float(v) for v in self.state_high)
        if len(lo) != 5 or len(hi) != 5:
            raise ValueError("state_low and state_high must have 5 entries (x, y, theta, v_ctrl, v_tgt)")
        names = STATE_NAMES
        for n, a, b in zip(names, lo, hi):
            _range(f"state bounds for {n}", (a, b))
        set_("state_low", lo)
        set_("state_high", hi)
        set_("move_x", _range("move_x", self.move_x))
        set_("move_y", _range("move_y", self.move_y))
        set_("pour_theta", _range("pour_theta", self.pour_theta))
        set_("pour_hold", _range("pour_hold", self.pour_hold, 0.0))
        for key, rng_, i in (
            ("move_x", self.move_x, 0),
            ("move_y", self.move_y, 1),
            ("pour_theta", self.pour_theta, 2),
        ):
            if rng_[0] < lo[i] or rng_[1] > hi[i]:  # an action's target is a state: it must lie in the state box
                raise ValueError(
                    f"{key}={list(rng_)} reaches outside the state bounds of {names[i]} "
                    f"[{lo[i]}, {hi[i]}] (state_low[{i}], state_high[{i}]): widen them or narrow {key}"
                )
        lat = self.move_lattice
        if isinstance(lat, bool) or not isinstance(lat, (int, float)) or not math.isfinite(lat) or lat < 0:
            raise ValueError(f"move_lattice={lat!r}: allowed 0 (continuous move targets) or a spacing > 0 m")
        set_("move_lattice", float(lat))
        for key, (a, b) in (("move_x", self.move_x), ("move_y", self.move_y)):
            if lat and math.floor(b / lat + 1e-9) < math.ceil(a / lat - 1e-9):
                raise ValueError(
                    f"{key}={[a, b]} holds no multiple of move_lattice={lat:g} m: no move target "
                    "could be executed; widen the range or change the lattice"
                )
        w = tuple(float(v) for v in self.distance_weights)
        if len(w) != 4 or any(not math.isfinite(v) or v < 0 for v in w) or sum(w) == 0:
            raise ValueError(f"distance_weights must be 4 finite non-negative numbers, not all 0; got {w}")
        set_("distance_weights", w)
        if not 0.0 <= self.p_move <= 1.0:
            raise ValueError(f"p_move={self.p_move} outside allowed range [0, 1]")
        if int(self.max_actions) < 1:
            raise ValueError(f"max_actions={self.max_actions} must be >= 1")
        if not self.goal_tol > 0:
            raise ValueError(f"goal_tol={self.goal_tol} must be > 0")
        if self.accept_tol is not None and not self.accept_tol >= self.goal_tol:
            raise ValueError(f"accept_tol={self.accept_tol}: allowed None or >= goal_tol={self.goal_tol}")
        if not self.stuck_tilt > 0:
            raise ValueError(f"stuck_tilt={self.stuck_tilt} must be > 0 rad")
        if not self.stuck_move > 0:
            raise ValueError(f"stuck_move={self.stuck_move} must be > 0 m")
        if not 0.0 <= self.spill_limit <= 1.0:
            raise ValueError(f"spill_limit={self.spill_limit} outside allowed range [0, 1]")
        if not (math.isfinite(self.beta) and math.isfinite(self.d_max)):
            raise ValueError("beta and d_max must be finite")
        if int(self.n_candidates) < 1:
            raise ValueError(f"n_candidates={self.n_candidates} must be >= 1")
        if not self.time_budget > 0:
            raise ValueError(f"time_budget={self.time_budget} must be > 0 (seconds)")
        if int(self.propagation_budget) < 1:
            raise ValueError(f"propagation_budget={self.propagation_budget} must be >= 1")
        if not 0.0 <= self.goal_bias <= 1.0:
            raise ValueError(f"goal_bias={self.goal_bias} outside allowed range [0, 1]")
        if int(self.last_step_proposals) < 1:
            raise ValueError(f"last_step_proposals={self.last_step_proposals} must be >= 1")
        if not 1 <= int(self.batch_min) <= int(self.batch_max):
            raise ValueError(f"need 1 <= batch_min <= batch_max, got {self.batch_min}, {self.batch_max}")
        if (
            not isinstance(self.torch_threads, (int, float))
            or isinstance(self.torch_threads, bool)
            or int(self.torch_threads) != self.torch_threads
            or self.torch_threads < 0
        ):
            raise ValueError(
                f"torch_threads={self.torch_threads!r} must be an integer >= 1, or 0 to leave torch's setting alone"
            )
        set_("torch_threads", int(self.torch_threads))
        if self.ompl_log_level not in _LOG_LEVELS:
            raise ValueError(f"ompl_log_level={self.ompl_log_level!r} not one of {sorted(_LOG_LEVELS)}")
        for k in (
            "max_actions",
            "n_candidates",
            "propagation_budget",
            "seed",
            "batch_min",
            "batch_max",
            "last_step_proposals",
        ):
            set_(k, int(getattr(self, k)))

    # -- conversion ----------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None = None, **overrides: Any) -> "PlannerConfig":
        """Build from a (Hydra/OmegaConf or plain) mapping; unknown keys are an error."""
        data: dict[str, Any] = dict(_to_plain(d) or {})
        data.update(overrides)
        data.pop("_target_", None)
        return cls(**_known(cls, data, "planner config"))

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict with lists for ranges (the YAML layout)."""

        def conv(v: Any) -> Any:
            if dataclasses.is_dataclass(v):
                return {f.name: conv(getattr(v, f.name)) for f in fields(v)}
            if isinstance(v, tuple):
                return [conv(x) for x in v]
            return v

        return conv(self)

    def replace(self, **changes: Any) -> "PlannerConfig":
        return dataclasses.replace(self, **changes)


_LOG_LEVELS = {"none", "error", "warn", "info", "debug"}


def _known(cls: type, data: Mapping[str, Any], what: str) -> dict[str, Any]:
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ValueError(f"unknown {what} key(s) {unknown}; allowed: {sorted(names)}")
    return dict(data)


def _to_plain(d: Any) -> Any:
    """Convert an OmegaConf container to plain Python. omegaconf is imported here, not at the top: planner
    worker processes import this module and never get a Hydra node."""
    if d is None:
        return None
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf

        if isinstance(d, (DictConfig, ListConfig)):
            return OmegaConf.to_container(d, resolve=True)
    except ImportError:  # pragma: no cover - omegaconf is a project dependency
        pass
    return d
