"""What a run waits for, and how it is served.

An iteration of a run (:meth:`active.loop.MethodRun.iteration_steps`) yields planner calls
(:class:`PlanNeed`) and target-world simulations (:class:`SimNeed`); a run alone or a round of
runs batched together (:mod:`active.lockstep`) serves them with the same results.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from planner.pool import PlanRequest
from sim.execute import PouringExecutor
from sim.skills import pour
from task.problems import Problem

#: one row per test problem (``tests.csv``, ``model_only.csv``): what became of each problem, not only the rates
OUTCOME_FIELDS = ["problem", "goal", "found", "goal_reached", "category", "final_spill"]
NOOP = np.array([pour(0.0, 0.0)])  # padding trajectory: keeps the number of batch sizes (compiled solvers) small


@dataclass
class PlanNeed:
    """Planner calls a run waits for, all with one MDE (None: the model alone)."""

    requests: list[PlanRequest]
    mde: Any


@dataclass
class SimNeed:
    """Trajectories a run waits for, executed in the target world; ``batch``: the most a run's need of this
    kind holds (a training chunk, the test problems). Trajectory k samples its water as slot k, or as
    ``slots[k]`` where given (the oracle's candidates of one problem share its slot)."""

    problems: list[Problem]
    actions: list[np.ndarray]
    batch: int
    slots: list[int] | None = None


def execute_needs(executor: PouringExecutor, needs: list[SimNeed]) -> list[list]:
    """Every need's trajectories in one target-world simulation; ``out[i]`` are ``needs[i]``'s results.

    Each trajectory keeps the particle-sampling slot it has when its run executes alone, and the
    environments of a batch do not interact, so a run's results do not depend on what else is in the
    batch (bit for bit on the CPU). The batch is padded with do-nothing trajectories to the next power
    of two, at most the sum of the needs' ``batch``: few sizes, so few compiled solvers, and few pads
    (a round of 20 runs whose 30 test problems gave 10 plans simulates 16 environments, not 600).
    """
    probs = [p for n in needs for p in n.problems]
    if not probs:
        return [[] for _ in needs]
    for n in needs:
        if (
            len(n.problems) != len(n.actions)
            or len(n.problems) > n.batch
            or len(n.slots or n.problems) != len(n.problems)
        ):
            raise ValueError(f"SimNeed: {len(n.problems)} problems, {len(n.actions)} action sequences, batch {n.batch}")
    actions = [a for n in needs for a in n.actions]
    slots = [k for n in needs for k in (n.slots if n.slots is not None else range(len(n.problems)))]
    size = min(sum(n.batch for n in needs), 1 << (len(probs) - 1).bit_length())
    pad = size - len(probs)
    slots += range(len(probs), size)  # the pads' own slots (unused by any trajectory)
    starts = np.array([p.start[:3] for p in probs] + [probs[0].start[:3]] * pad)
    jit = np.array([p.plant_jitter for p in probs] + [probs[0].plant_jitter] * pad)
    goals = [p.goal for p in probs] + [probs[0].goal] * pad
    res = executor.run("target", starts, actions + [NOOP] * pad, plant_jitter=jit, goals=goals, slots=slots)
    out, i = [], 0
    for n in needs:
        out.append(res[i : i + len(n.problems)])
        i += len(n.problems)
    return out


def problem_outcomes(problems: Sequence[Problem], executed: Mapping[int, Any]) -> list[dict]:
    """One row per test problem (:data:`OUTCOME_FIELDS`): ``executed`` maps the index of each problem whose
    plan was found to its execution result; the others are rows with ``found`` False and no category."""
    rows = []
    for k, p in enumerate(problems):
        r = executed.get(k)
        rows.append(
            {
                "problem": k,
                "goal": round(float(p.goal), 4),
                "found": r is not None,
                "goal_reached": bool(r is not None and r.goal_reached),
                "category": r.category if r is not None else "",
                "final_spill": round(float(r.final_spill), 4) if r is not None else "",
            }
        )
    return rows
