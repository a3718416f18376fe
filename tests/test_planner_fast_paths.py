"""The planner's fast paths compute what their plain versions do: the contact check's touch test without
obstacle indices, and numpy's BLAS held on one thread while a plan runs (and restored after)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.contact import ContactPredictor
from sim.world import WorldConfig


@pytest.fixture(scope="module")
def predictor() -> ContactPredictor:
    return ContactPredictor(WorldConfig.load())


def test_touch_test_agrees_with_the_clearance_bit_for_bit(predictor: ContactPredictor) -> None:
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(0.0, 0.6, 20_000), rng.uniform(0.0, 0.4, 20_000), rng.uniform(-2, 2, 20_000)])
    touch = predictor._touching(poses[:, 0], poses[:, 1], poses[:, 2])
    d, _ = predictor._clearance(poses[:, None])
    assert touch.sum() > 1000 and (~touch).sum() > 1000  # both outcomes are exercised
    np.testing.assert_array_equal(touch, d[:, 0] < predictor.margin)


def test_exact_distances_give_the_same_touch_test() -> None:
    exact = ContactPredictor(WorldConfig.load(), resolution=None)
    rng = np.random.default_rng(1)
    poses = np.column_stack([rng.uniform(0.0, 0.6, 3000), rng.uniform(0.0, 0.4, 3000), rng.uniform(-2, 2, 3000)])
    d, _ = exact._clearance(poses[:, None])
    np.testing.assert_array_equal(exact._touching(*poses.T), d[:, 0] < exact.margin)


def test_blas_runs_on_one_thread_during_a_plan_and_is_restored() -> None:
    from threadpoolctl import threadpool_info

    from planner import Planner, PlannerConfig
    from planner.rrt import _one_blas_thread
    from tests.doubles.standins import AnalyticPouringModel

    def blas_threads() -> list[int]:
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    before = blas_threads()
    with _one_blas_thread():
        assert set(blas_threads()) == {1}
    assert blas_threads() == before
    seen: list[list[int]] = []
    model = AnalyticPouringModel()
    inner = model.predict

    def spy(states, actions):
        seen.append(blas_threads())
        return inner(states, actions)

    model.predict = spy
    Planner(model, None, PlannerConfig(propagation_budget=64)).plan(np.array([0.2, 0.2, 0.0, 1.0, 0.0]), 0.5, seed=0)
    assert seen and all(set(s) <= {1} for s in seen)
    assert blas_threads() == before
