"""Refinement of planned pours (active.refine): which pour is refined, its goal, failures recorded."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from active.experiment import ExperimentConfig
from active.refine import last_pour, refine_plans
from sim.world import WorldConfig


def _plan(actions, states):
    return SimpleNamespace(actions=np.array(actions, float), states=np.array(states, float))


def test_last_pour():
    assert last_pour(np.array([[0, 0.3, 0.2], [1, 1.2, 0.5], [0, 0.3, 0.1], [1, 1.4, 0.2]])) == 3
    assert last_pour(np.array([[0, 0.3, 0.2]])) is None


def test_plans_without_a_usable_pour_are_left_alone():
    world = WorldConfig.load()
    no_pour = _plan([[0, 0.3, 0.2]], [[0.4, 0.2, 0, 1, 0], [0.3, 0.2, 0, 1, 0]])
    empty = _plan([[1, 1.5, 0.5]], [[0.3, 0.2, 0, 0.0, 0.9], [0.3, 0.2, 0, 0.0, 0.9]])
    res = refine_plans(world, [no_pour, empty], [0.5, 0.5], steps=1, progress=False)
    assert not res.refined.any()
    assert set(res.skipped) == {0, 1} and "no pour" in res.skipped[0] and "empty" in res.skipped[1]
    for a, p in zip(res.actions, (no_pour, empty)):
        np.testing.assert_array_equal(a, p.actions)


def test_a_pour_that_cannot_be_simulated_is_recorded_not_raised():
    world = WorldConfig.load()
    tx = world.target_pose()[0]
    inside_target = _plan(
        [[1, 1.5, 0.5]], [[tx + 0.07, 0.07, 0, 1, 0], [tx + 0.07, 0.07, 0, 0.2, 0.8]]
    )  # overlaps the target cup
    res = refine_plans(world, [inside_target], [0.6], steps=1, progress=False)
    assert not res.refined[0] and "refinement failed" in res.skipped[0] and "overlaps" in res.skipped[0]
    np.testing.assert_array_equal(res.actions[0], inside_target.actions)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"refine_steps": -1}, "refine_steps"),
        ({"refine_lr": 0.0}, "refine_lr"),
        ({"known_obstacles": "yes"}, "known_obstacles"),
    ],
)
def test_experiment_refine_options_are_validated(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ExperimentConfig.from_mapping(kwargs)
