"""The oracle bound's pieces (:mod:`active.oracle`): its score, its tie-break, its refusal of a bad setting. The loop's
side (every candidate executed, the best one's data kept) is checked on a tiny run in
``tests/test_active_loop_records.py``."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from active.methods import OracleBound, build_method
from active.oracle import admission_gap, best, score_candidates


class _FixedMDE:
    """Predicts a given mean and std per row; ``fit`` remembers what it was given (or raises)."""

    def __init__(self, mean, std, fail: bool = False):
        self.mean, self.std, self.fail, self.seen = torch.tensor(mean), torch.tensor(std), fail, None
        self.is_fitted = False

    def fit(self, X, y):
        if self.fail:
            raise torch.linalg.LinAlgError("singular")
        self.seen, self.is_fitted = (X.clone(), y.clone()), True

    def predict(self, X):
        return self.mean[: len(X)], self.std[: len(X)]


def test_the_admission_gap_is_the_share_of_good_admitted_minus_the_share_of_bad_admitted():
    # rows: good admitted, good refused (by beta * std), bad admitted, bad refused
    mde = _FixedMDE([0.01, 0.05, 0.02, 0.2], [0.0, 0.02, 0.01, 0.0])
    y = torch.tensor([0.01, 0.03, 0.09, 0.30])
    assert admission_gap(mde, torch.zeros(4, 8), y, d_max=0.07, beta=2.0) == pytest.approx(0.5 - 0.5)
    assert admission_gap(mde, torch.zeros(4, 8), y, d_max=0.07, beta=0.0) == pytest.approx(1.0 - 0.5)
    only_good = torch.tensor([0.01, 0.03, 0.05, 0.06])  # no bad transition: that side counts 0
    assert admission_gap(mde, torch.zeros(4, 8), only_good, d_max=0.07, beta=2.0) == pytest.approx(0.5)


def test_each_candidate_is_scored_by_a_fresh_fit_on_the_data_plus_its_own_and_a_failed_fit_scores_minus_inf():
    made: list[_FixedMDE] = []

    def make_mde():
        made.append(_FixedMDE([0.01, 0.2], [0.0, 0.0], fail=len(made) == 1))  # the second fit fails
        return made[-1]

    X, y = torch.ones(3, 8), torch.full((3,), 0.5)
    cands = [(torch.full((2, 8), 2.0), torch.zeros(2)), (torch.zeros(1, 8), torch.zeros(1)), (X[:0], y[:0])]
    val = {"X": torch.zeros(2, 8), "y": torch.tensor([0.01, 0.3])}
    with pytest.warns(RuntimeWarning, match="oracle: an MDE fit failed"):
        scores = score_candidates(make_mde, X, y, cands, val, d_max=0.07, beta=2.0)
    assert scores[0] == pytest.approx(1.0) and scores[1] == -math.inf and scores[2] == pytest.approx(1.0)
    assert len(made) == 3
    assert torch.equal(made[0].seen[0], torch.cat([X, cands[0][0]])) and torch.equal(made[2].seen[1], y)


def test_ties_are_broken_at_random_among_the_best_only():
    picks = {best([0.2, 0.5, 0.5, -math.inf], np.random.default_rng(s)) for s in range(40)}
    assert picks == {1, 2}
    assert best([0.1, 0.3, 0.2], np.random.default_rng(0)) == 1


def test_the_oracle_is_built_from_the_registry_and_refuses_a_validation_set_too_small_to_score():
    oracle = build_method("oracle")
    assert isinstance(oracle, OracleBound)
    assert (oracle.score, oracle.validation_problems, oracle.validation_trajectories) == ("success", 10, 64)
    with pytest.raises(ValueError, match="validation_trajectories = 1: allowed an integer >= 2"):
        OracleBound(validation_trajectories=1)
    with pytest.raises(ValueError, match="validation_problems = 0: allowed an integer >= 1"):
        OracleBound(validation_problems=0)
    with pytest.raises(ValueError, match=r"score = 'gap': allowed one of \['success', 'admission'\]"):
        OracleBound(score="gap")
    with pytest.raises(TypeError, match="chooses after executing every candidate"):
        OracleBound().choose([], np.random.default_rng(0), lambda: None)
