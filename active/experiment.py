"""Experiment protocol settings, validated before any compute."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Mapping

from .methods import METHODS, check_method

#: what a plan-using method executes when none of a problem's candidate searches found a plan
ALLOWED_FALLBACKS = ("random_actions", "model_plan")


@dataclass(frozen=True)
class ExperimentConfig:
    """The protocol of one experiment (``configs/experiment/<name>.yaml``, the ``experiment:`` block).

    The YAMLs are the source of truth: each sets every field (tests/test_config_overrides.py), and the
    defaults here are those of ``experiment=quick``, the default experiment. The planner's candidates,
    d_max and budgets are interpolated from here into ``configs/planner/default.yaml``.
    """

    name: str = "quick"
    methods: tuple[str, ...] = ("active_balanced", "random_plan")
    iterations: int = 8
    trajectories_per_iteration: int = 6
    refit_every: int = 6
    candidates: int = 5
    test_problems: int = 10
    random_actions_length: int = 6
    d_max: float = 0.07
    beta_train: tuple[float, float] = (-2.0, 1.0)
    beta_switch_iteration: int = 4
    beta_test: float = 2.0
    calibration_trajectories: int = 8
    planner_propagation_budget: int = 10000  # per candidate: the deterministic budget (the paper's)
    planner_time_budget: float = 30.0  # s per candidate: a safety net only (wall clock is not reproducible)
    #: the planner's model knows the source world's static obstacles (target cup, tank walls) and
    #: predicts moves / pours that hit them as stuck (dynamics.ContactAwareDynamics); the plant stays unknown
    known_obstacles: bool = True
    #: > 0: at test time, also execute every found plan with its last pour refined by this many
    #: gradient steps in the differentiable source-world simulator (active.refine); results.csv gets
    #: test_success_refined beside test_success (unrefined). Costs ~30 s per step for 8 pours on 2 cores
    refine_steps: int = 0
    refine_lr: float = 0.05
    #: the planner accepts a predicted end state whose |v_tgt - goal| is within this (null: the world's goal
    #: tolerance). Smaller aims plans at the middle of the goal band, so that the executed pour, which
    #: scatters about the prediction, still lands inside the protocol's tolerance (not changed by this)
    plan_goal_tol: float | None = 0.025
    #: with a narrower plan_goal_tol: when the planner's budget runs out without a plan within plan_goal_tol, it
    #: returns the plan whose predicted end is closest to the goal within this band (null: no such fallback).
    #: So the aim costs no plans that the wider band finds (at most world.problems.tolerance)
    plan_accept_tol: float | None = 0.05
    #: the planner accepts a predicted end state whose spill is at most this (null: the world's max_spill).
    #: Smaller keeps a margin for pours that spill more than the model predicts (the precondition's d_max
    #: admits deviations several times the spill limit); success is always judged with world.problems.max_spill
    plan_spill_limit: float | None = 0.012
    #: what a method that plans executes when the planner found no candidate the MDE admits:
    #: "random_actions" (a random-action sequence, marked "fallback") or "model_plan" (a plan of the
    #: model alone, no MDE, marked "fallback_plan"; random actions only if that finds nothing either).
    #: Why the second: random actions mostly end in the plant, and a round with no admitted candidate then
    #: adds large labels instead of data where plans go (BENCHMARKS.md, plan errors)
    fallback: str = "random_actions"

    @classmethod
    def from_mapping(
        cls, data: Mapping[str, Any], method: str = "all", registry: Mapping[str, Any] | None = None
    ) -> "ExperimentConfig":
        """Checked settings; ``method`` (not ``all``) narrows ``methods`` to it; ``registry`` is the run's
        ``methods:`` node (default: the shipped methods), which every method name must be in."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown experiment key(s) {unknown}; known keys: {sorted(known)}")
        d = dict(data)
        d["methods"] = tuple(d.get("methods", cls.methods))
        d["beta_train"] = tuple(float(b) for b in d.get("beta_train", cls.beta_train))
        if method != "all":
            d["methods"] = (check_method(method, registry),)
        cfg = cls(**d)
        cfg.validate(registry)
        return cfg

    def validate(self, registry: Mapping[str, Any] | None = None) -> None:
        if not self.methods:
            raise ValueError(f"experiment.methods is empty: allowed a list from {sorted(registry or METHODS)}")
        for m in self.methods:
            check_method(m, registry)
        for name in (
            "iterations",
            "trajectories_per_iteration",
            "refit_every",
            "candidates",
            "test_problems",
            "random_actions_length",
            "calibration_trajectories",
            "planner_propagation_budget",
        ):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ValueError(f"experiment.{name} = {v!r}: allowed an integer >= 1")
        if not 1 <= self.random_actions_length <= 6:
            raise ValueError(f"experiment.random_actions_length = {self.random_actions_length}: allowed 1..6")
        if not self.d_max > 0:
            raise ValueError(f"experiment.d_max = {self.d_max}: allowed > 0")
        if len(self.beta_train) != 2:
            raise ValueError(f"experiment.beta_train = {self.beta_train}: allowed [beta_early, beta_late]")
        if self.beta_switch_iteration < 0:
            raise ValueError(f"experiment.beta_switch_iteration = {self.beta_switch_iteration}: allowed >= 0")
        if not isinstance(self.refine_steps, int) or self.refine_steps < 0:
            raise ValueError(f"experiment.refine_steps = {self.refine_steps!r}: allowed an integer >= 0 (0 = off)")
        if not self.refine_lr > 0:
            raise ValueError(f"experiment.refine_lr = {self.refine_lr!r}: allowed > 0")
        if not isinstance(self.known_obstacles, bool):
            raise ValueError(f"experiment.known_obstacles = {self.known_obstacles!r}: allowed true or false")
        if self.plan_goal_tol is not None and not 0 < self.plan_goal_tol <= 1:
            raise ValueError(
                f"experiment.plan_goal_tol = {self.plan_goal_tol!r}: allowed null or a fraction in (0, 1] "
                f"(at most world.problems.tolerance)"
            )
        # against the goal band and the world's tolerance: active.planner_setup.build_planner_config
        if self.plan_accept_tol is not None and not 0 < self.plan_accept_tol <= 1:
            raise ValueError(
                f"experiment.plan_accept_tol = {self.plan_accept_tol!r}: allowed null or a fraction in "
                f"(0, 1] (from the planner's goal band to world.problems.tolerance)"
            )
        if self.plan_spill_limit is not None and not 0 <= self.plan_spill_limit <= 1:
            raise ValueError(
                f"experiment.plan_spill_limit = {self.plan_spill_limit!r}: allowed null or a fraction "
                f"in [0, 1] (at most world.problems.max_spill)"
            )
        if self.fallback not in ALLOWED_FALLBACKS:
            raise ValueError(f"experiment.fallback = {self.fallback!r}: allowed one of {ALLOWED_FALLBACKS}")
        if not self.planner_time_budget > 0:
            raise ValueError(f"experiment.planner_time_budget = {self.planner_time_budget}: allowed > 0 s")

    def beta(self, iteration: int) -> float:
        """Training precondition beta for a 0-based iteration (paper: -2 before iteration 10, 1 after)."""
        return self.beta_train[0] if iteration < self.beta_switch_iteration else self.beta_train[1]
