"""The oracle bound: how much better than a random pick any choice among the same candidates can be.

Not a method a robot could run: each round it executes all N candidates of a problem (one simulation batch) and
keeps, as the trajectory it learns from, the candidate whose data score best on held-out target-world data. So it
sees what no acquisition may see: every candidate's real outcome and the held-out truth. What it answers: choosing
among the candidates random_plan chooses from (common random numbers, :mod:`active.seeds`), how much better can data
collection get? The report draws it as a bound. Choices are greedy within a chunk: a problem's candidates are scored
with the data of the problems before it in the chunk.

Two scores (``active.methods.OracleBound``):

* ``success`` (default; scored by ``active.loop.MethodRun``, which plans and executes): the endpoint itself, the test
  planner's success on ``validation_problems`` held-out problems (a stream of their own, disjoint from the test
  problems) with an MDE fitted on the data plus the candidate's. Cost per round: N x M extra trajectories, N x M MDE
  fits, N x M x ``validation_problems`` plans and executions.
* ``admission`` (:func:`admission_gap`): the test precondition's admission of good transitions (true deviation below
  ``d_max``) minus its admission of bad ones on a held-out set of ``validation_trajectories`` trajectories (half plans
  of the model alone, half random actions: the ladder's ceiling recipe), made once per run. Cheaper, and refuted by a
  pilot: the admission gap of MDEs of a few dozen transitions is not their plan-found rate (results/headroom/).
"""

from __future__ import annotations

import math
import warnings
from typing import Any, Callable, Sequence

import numpy as np
import torch

#: the names of bounds in the ``methods:`` registry: reported as bounds (dashed, "bound" in the legend), never as the
#: best method of a run (``active.run.headline``)
BOUND_NAMES = ("oracle",)


def admission_gap(mde: Any, X: torch.Tensor, y: torch.Tensor, d_max: float, beta: float) -> float:
    """Share of the good transitions (``y < d_max``) the precondition ``mu + beta sigma < d_max`` admits, minus the
    share of the bad ones it admits; a side with no transitions counts 0. In [-1, 1]; higher is better."""
    with torch.no_grad():
        mean, std = mde.predict(torch.as_tensor(X, dtype=torch.float64))
    admitted = (torch.as_tensor(mean).reshape(-1) + beta * torch.as_tensor(std).reshape(-1) < d_max).double()
    good = torch.as_tensor(y).reshape(-1) < d_max

    def share(mask: torch.Tensor) -> float:
        return float(admitted[mask].mean()) if bool(mask.any()) else 0.0

    return share(good) - share(~good)


def score_candidates(
    make_mde: Callable[[], Any],
    X: torch.Tensor,
    y: torch.Tensor,
    candidates: Sequence[tuple[torch.Tensor, torch.Tensor]],
    validation: dict,
    d_max: float,
    beta: float,
) -> list[float]:
    """The validation admission gap of a fresh MDE fitted on (X, y) plus each candidate's labelled transitions
    (``candidates[k] = (X_k, y_k)``); a fit that fails scores -inf (recorded in the choice's scores)."""
    scores = []
    for Xc, yc in candidates:
        mde = make_mde()
        try:
            mde.fit(torch.cat([X, Xc]), torch.cat([y, yc]))
            scores.append(
                admission_gap(mde, validation["X"], validation["y"], d_max, beta) if mde.is_fitted else -math.inf
            )
        except Exception as err:  # noqa: BLE001 - one failed fit must not end a long run: that candidate scores -inf
            warnings.warn(
                f"oracle: an MDE fit failed ({type(err).__name__}: {err}); its candidate scores -inf",
                RuntimeWarning,
                stacklevel=2,
            )
            scores.append(-math.inf)
    return scores


def best(scores: Sequence[float], rng: np.random.Generator) -> int:
    """Index of the highest score; ties (frequent: admission is a share of a finite set) broken at random."""
    top = np.flatnonzero(np.asarray(scores) == np.max(scores))
    return int(top[0] if len(top) == 1 else rng.choice(top))
