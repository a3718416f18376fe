"""Gradient refinement of planned pours in the differentiable source-world simulator (sim.diff),
and a check of what it does to test-time success.

Why: the planner's pour parameters come from the learned model, whose error on partial pours is
larger than the goal tolerance; the simulator of the source world can be differentiated. Each plan's
last pour (theta, hold) is refined from the plan's predicted state before it (cup position, water
left in the cup) towards the amount the goal still needs, then the plan is executed as usual.

    python -m benchmarks.refine_check RUN_DIR [--method active_balanced] [--steps 5]   (see benchmarks/refine_check.py)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

POUR = 1


@dataclass
class RefinedPlans:
    """Refined action sequences (same order as the input) and what the refinement saw."""

    actions: list[np.ndarray]
    refined: np.ndarray  # (n,) bool: this plan's last pour was refined
    params_before: np.ndarray  # (m, 4) x, y, theta, hold of the refined pours
    params_after: np.ndarray
    pour_goal: np.ndarray  # (m,) fraction of the cup's water the pour should move to the target
    loss_before: np.ndarray
    loss_after: np.ndarray
    skipped: dict[int, str] = field(default_factory=dict)  # plan index -> why it was left alone
    wall_seconds: float = 0.0


def last_pour(actions: np.ndarray) -> int | None:
    """Index of a plan's last pour action, or None."""
    idx = np.flatnonzero(np.rint(np.asarray(actions)[:, 0]) == POUR)
    return int(idx[-1]) if idx.size else None


def _last_pours(plans: Sequence[Any], goals: Sequence[float]) -> tuple[list, list, list, list, dict]:
    """Per plan with a pour from a cup that holds water: (plan index, action index) of its last pour, the pour's
    parameters (x, y, theta, hold), the water in the cup before it and the share of that water the goal needs; and
    why each other plan is skipped."""
    rows, params, v_ctrl, pour_goal, skipped = [], [], [], [], {}
    for i, (p, g) in enumerate(zip(plans, goals)):
        k = last_pour(p.actions)
        if k is None:
            skipped[i] = "no pour"
            continue
        s = np.asarray(p.states[k], float)
        if s[3] <= 0.02:
            skipped[i] = "cup (nearly) empty before the pour"
            continue
        rows.append((i, k))
        params.append([s[0], s[1], p.actions[k][1], p.actions[k][2]])
        v_ctrl.append(min(float(s[3]), 1.0))
        pour_goal.append(float(np.clip((g - s[4]) / s[3], 0.0, 1.0)))
    return rows, params, v_ctrl, pour_goal, skipped


def refine_plans(
    world: Any,
    plans: Sequence[Any],
    goals: Sequence[float],
    *,
    steps: int = 5,
    lr: float = 0.05,
    spill_weight: float = 1.0,
    wrt: Sequence[str] = ("theta", "hold"),
    progress: bool = True,
    **sim_kwargs: Any,
) -> RefinedPlans:
    """Refine the last pour of each plan (``planner.Trajectory``: actions, predicted states) in one batch.

    The pour's goal is the share of the water still in the cup that must reach the target:
    (g - v_tgt) / v_ctrl of the predicted state before the pour, clipped to [0, 1]. Plans without a
    pour, or whose pour cannot be simulated (e.g. an empty cup), are left unchanged and listed in
    ``skipped``.
    """
    import time

    from sim.diff import refine_pours
    from sim.engine.config import ConfigError

    t0 = time.perf_counter()
    out = [np.array(p.actions, float, copy=True) for p in plans]
    rows, params, v_ctrl, pour_goal, skipped = _last_pours(plans, goals)
    refined = np.zeros(len(plans), bool)
    empty = np.zeros((0, 4))
    if not rows:
        return RefinedPlans(
            out, refined, empty, empty, np.zeros(0), np.zeros(0), np.zeros(0), skipped, time.perf_counter() - t0
        )
    params_a = np.array(params)
    try:
        res = refine_pours(
            world,
            params_a,
            np.array(pour_goal),
            v_ctrl=np.array(v_ctrl),
            steps=steps,
            lr=lr,
            wrt=tuple(wrt),
            spill_weight=spill_weight,
            progress=progress,
            **sim_kwargs,
        )
    except ConfigError as e:  # recorded, the run goes on with the unrefined plans
        for i, _ in rows:
            skipped[i] = f"refinement failed: {e}"
        return RefinedPlans(
            out,
            refined,
            params_a,
            params_a,
            np.array(pour_goal),
            np.full(len(rows), np.nan),
            np.full(len(rows), np.nan),
            skipped,
            time.perf_counter() - t0,
        )
    for r, (i, k) in enumerate(rows):
        out[i][k, 1], out[i][k, 2] = res.params[r, 2], res.params[r, 3]
        refined[i] = not res.failed[r]
        if res.failed[r]:
            skipped[i] = "refinement went NaN"
    return RefinedPlans(
        out,
        refined,
        params_a,
        res.params,
        np.array(pour_goal),
        res.loss_initial,
        res.loss_best,
        skipped,
        time.perf_counter() - t0,
    )
