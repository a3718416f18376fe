"""The planner settings of a run: one :class:`planner.PlannerConfig` from the ``planner:`` block, checked
against the world and the experiment, and the model the run plans with.

Several planner values are the world's or the experiment's (the skills' ranges, the spill limit, d_max,
the budgets): ``configs/planner/default.yaml`` interpolates them, and a run whose planner value differs
from its source is refused, so each is set in one place.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping

import dynamics
from planner import PlannerConfig
from planner.pool import resolve_workers
from sim.world import WorldConfig

from .experiment import ExperimentConfig

#: planner keys the world or the experiment fixes: ``configs/planner/default.yaml`` interpolates them from
#: their source, and a run whose planner value differs from the source's (set on the planner side) is refused
DERIVED_PLANNER_KEYS = {
    "move_x": "world.skills.move.x",
    "move_y": "world.skills.move.y",
    "pour_theta": "world.skills.pour.theta",
    "pour_hold": "world.skills.pour.hold",
    "max_actions": "world.skills.max_actions",
    "spill_limit": "world.problems.max_spill",
    "d_max": "experiment.d_max",
    "n_candidates": "experiment.candidates",
    "time_budget": "experiment.planner_time_budget",
    "propagation_budget": "experiment.planner_propagation_budget",
}
#: PlannerConfig fields that are no settings of a run, and where their values come from instead
NOT_RUN_SETTINGS = {
    "beta": "experiment.beta_train / experiment.beta_test (passed with every planning call)",
    "seed": "the run's seed (every planning call derives its own)",
    "goal_tol": "experiment.plan_goal_tol (null: world.problems.tolerance)",
    "accept_tol": "experiment.plan_accept_tol (null: no fallback band)",
    "move_lattice": "world.skills.lattice (absent: 0, continuous move targets)",
}


def planning_dynamics(
    dynamics_cfg: dynamics.DynamicsConfig, world: WorldConfig, exp: ExperimentConfig, progress: bool = False
) -> Any:
    """The model the experiment plans with: the cached source-world dynamics model of ``dynamics_cfg`` in ``world``'s
    source world (trained on first use), wrapped with the known static geometry when ``experiment.known_obstacles``."""
    dyn = dynamics.load_or_train(dynamics_cfg, world_cfg=world, progress=progress)
    return dynamics.ContactAwareDynamics(dyn, world) if exp.known_obstacles else dyn


def build_planner_config(world: WorldConfig, planner: Mapping[str, Any], exp: ExperimentConfig) -> PlannerConfig:
    """The run's :class:`PlannerConfig` from the ``planner:`` block, checked against world and experiment.

    The keys of :data:`DERIVED_PLANNER_KEYS` must equal their source (the YAML interpolates them; an
    absent one is taken from the source); the goal band is ``experiment.plan_goal_tol`` or the world's
    tolerance, its fallback band ``experiment.plan_accept_tol``, the spill limit ``experiment.plan_spill_limit`` or
    the world's ``max_spill``. Unknown keys and :data:`NOT_RUN_SETTINGS` are refused, naming the allowed keys.
    ``planner.workers`` is validated here but is not a :class:`PlannerConfig` field (it says where plans
    are computed, not what they are): see :func:`planner_workers`.
    """
    d = dict(planner)
    d.pop("_target_", None)
    planner_workers(d)
    d.pop("workers", None)
    allowed = sorted(({f.name for f in dataclasses.fields(PlannerConfig)} - set(NOT_RUN_SETTINGS)) | {"workers"})
    unknown = sorted(set(d) - set(allowed) - set(NOT_RUN_SETTINGS))
    if unknown:
        raise ValueError(f"unknown planner key(s) {['planner.' + k for k in unknown]}; allowed: {allowed}")
    fixed = sorted(set(d) & set(NOT_RUN_SETTINGS))
    if fixed:
        raise ValueError(
            "; ".join(f"planner.{k} is not a setting of a run: its value is {NOT_RUN_SETTINGS[k]}" for k in fixed)
        )
    for k, src in DERIVED_PLANNER_KEYS.items():
        want = _source_value(src, world, exp)
        if k not in d:
            d[k] = want
        elif _plain(d[k]) != _plain(want):
            raise ValueError(
                f"planner.{k} = {d[k]!r} differs from {src} = {want!r}: the planner's value is "
                f"{src}'s (configs/planner/default.yaml interpolates it); set {src} instead"
            )
    d["goal_tol"] = _planner_bound(world, exp, "plan_goal_tol", "tolerance", "(")
    d["spill_limit"] = _planner_bound(world, exp, "plan_spill_limit", "max_spill", "[")
    if exp.plan_accept_tol is not None:
        d["accept_tol"] = _planner_bound(world, exp, "plan_accept_tol", "tolerance", "(")
        if d["accept_tol"] < d["goal_tol"]:
            raise ValueError(
                f"experiment.plan_accept_tol = {exp.plan_accept_tol}: allowed [{d['goal_tol']}, "
                f"{world.problems['tolerance']}] (from the planner's goal band to the world's tolerance)"
            )
    d["move_lattice"] = float(world.skills.get("lattice", 0.0))
    return PlannerConfig.from_dict(d)


def _source_value(path: str, world: WorldConfig, exp: ExperimentConfig) -> Any:
    head, *rest = path.split(".")
    if head == "experiment":
        return getattr(exp, rest[0])
    cur: Any = getattr(world, rest[0])
    for k in rest[1:]:
        cur = cur[k]
    return cur


def _plain(v: Any) -> Any:
    """Numbers as floats, sequences as tuples: ``[0.1, 0.52]`` (YAML) equals ``(0.1, 0.52)``."""
    if isinstance(v, (list, tuple)):
        return tuple(_plain(x) for x in v)
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return float(v)
    return v


def planner_workers(planner: Mapping[str, Any]) -> int:
    """Planner processes from ``planner.workers`` (an integer >= 1 or ``auto``; absent: ``auto``)."""
    return resolve_workers(planner.get("workers", "auto"), "planner.workers")


def _planner_bound(world: WorldConfig, exp: ExperimentConfig, exp_key: str, world_key: str, lower: str) -> float:
    """The planner's value of a bound the world sets (goal band, spill limit): ``world.problems[world_key]``, or
    the experiment's narrower ``exp_key``; success is always judged with the world's value. ``lower`` is the
    allowed range's opening bracket, for the error message."""
    limit = float(world.problems[world_key])
    value = getattr(exp, exp_key)
    if value is None:
        return limit
    if value > limit:
        raise ValueError(
            f"experiment.{exp_key} = {value}: allowed {lower}0, {limit}] "
            f"(world.problems.{world_key}; success is always judged with the world's value)"
        )
    return float(value)
