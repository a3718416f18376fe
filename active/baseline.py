"""The model alone on a seed's test problems: the line every MDE-based method has to beat.

Why: the test precondition only helps if it rejects the model's bad plans without losing its good
ones. Whether it does is a paired question per seed: the same test problems, planned with the same
planner and budget but no precondition (no MDE), executed in the target world. A run writes the
answer once per seed to ``model_only.csv`` (one row per test problem); :mod:`active.report` draws its
success rate as a line on the learning curves and compares each method's area under the curve with
it, paired over seeds. It changes no method's results (its planner seeds are its own, and batched
environments do not interact), so it is not part of a run's config digest; the file records the
digest of the config that made it and is rebuilt for another one.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

from .io import read_csv, write_csv

if TYPE_CHECKING:  # the report reads these files without importing the planner and the simulator
    from planner.pool import PlanPool
    from sim.execute import PouringExecutor
    from task.problems import Problem

log = logging.getLogger(__name__)

FILE = "model_only.csv"
FIELDS = [
    "seed",
    "problem",
    "goal",
    "found",
    "goal_reached",
    "category",
    "final_spill",
    "digest",
]  # needs.OUTCOME_FIELDS


def load(path: Path, digest: str, n: int) -> list[dict] | None:
    """The rows of ``path`` if the config with ``digest`` made all ``n`` of them, else None."""
    if not path.exists():
        return None
    rows = read_csv(path)
    if len(rows) == n and rows and all(r.get("digest") == digest for r in rows):
        return rows
    log.warning("%s was made by another configuration or is incomplete; rebuilding it", path)
    return None


def measure(
    pool: "PlanPool", executor: "PouringExecutor", problems: Mapping[int, Sequence["Problem"]], d_max: float
) -> dict[int, list[dict]]:
    """Plan every seed's test problems with the model alone (one planning batch) and execute the plans
    found (one target-world simulation); returns seed -> one row per problem (without the digest)."""
    from planner.pool import PlanRequest  # the report imports this module without the planner

    from .needs import SimNeed, execute_needs, problem_outcomes
    from .seeds import derive_seed

    seeds = list(problems)
    groups = [
        (
            [
                PlanRequest("plan", p.start, p.goal, d_max=d_max, seed=derive_seed(s, "model-only-plan", k))
                for k, p in enumerate(problems[s])
            ],
            None,
        )
        for s in seeds
    ]
    planned = pool.run_groups(groups, errors="record")
    found = {s: [r.trajectory if r.found else None for r in res] for s, res in zip(seeds, planned)}
    idx = {s: [k for k, t in enumerate(found[s]) if t is not None] for s in seeds}
    needs = [
        SimNeed([problems[s][k] for k in idx[s]], [found[s][k].actions for k in idx[s]], len(problems[s]))
        for s in seeds
    ]
    executed = execute_needs(executor, needs)
    return {
        s: [{"seed": s, **row} for row in problem_outcomes(problems[s], dict(zip(idx[s], results)))]
        for s, results in zip(seeds, executed)
    }


def save(path: Path, rows: list[dict], digest: str) -> list[dict]:
    rows = [{**r, "digest": digest} for r in rows]
    write_csv(path, rows, FIELDS)
    return rows


def rates(rows: Sequence[Mapping[str, Any]]) -> tuple[float, float]:
    """(success, found) rates of one seed's rows."""
    n = len(rows)
    if n == 0:
        return float("nan"), float("nan")
    return sum(is_true(r["goal_reached"]) for r in rows) / n, sum(is_true(r["found"]) for r in rows) / n


def is_true(value: Any) -> bool:
    """A boolean field of a row as written (True) or read back from CSV ("True")."""
    return str(value) in ("True", "true", "1")


def latest_rows(rows: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """One row per (seed, problem): a problem found in several files, e.g. one per job of a per-method sweep,
    counts once (the last row wins)."""
    return list({(str(r["seed"]), r["problem"]): r for r in rows}.values())
