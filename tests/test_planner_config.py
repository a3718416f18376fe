"""Planner config (and its YAML mirror), the shared action sampler and the interface helpers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from planner import (
    ActionSampler,
    DeviationEstimator,
    DynamicsModel,
    PlannerConfig,
    features,
    goal_distance,
    goal_reached,
    spill,
)
from planner.interfaces import describe_action, skill_ids, split_features
from tests.doubles.standins import AnalyticPouringModel, StandInGPMDE, StandInMLPDynamics, ToyBoxMDE, ToyPointRobot

YAML = Path(__file__).resolve().parents[1] / "configs" / "planner" / "default.yaml"


def test_yaml_mirrors_dataclass_defaults():
    """Planner-only keys mirror the defaults; the task's and the protocol's are interpolated (world, experiment:
    tests/test_config_overrides.py); beta, seed and goal_tol come with the run's planning calls, accept_tol from
    experiment.plan_accept_tol."""
    d = yaml.safe_load(YAML.read_text())
    assert d.pop("workers") == "auto"  # process count of planner.pool, deliberately not a PlannerConfig field
    derived = {k for k, v in d.items() if isinstance(v, str) and v.startswith("${")}
    assert derived == {
        "move_x",
        "move_y",
        "pour_theta",
        "pour_hold",
        "max_actions",
        "spill_limit",
        "d_max",
        "n_candidates",
        "time_budget",
        "propagation_budget",
    }
    default = PlannerConfig().to_dict()
    assert set(default) - set(d) == {"beta", "seed", "goal_tol", "accept_tol", "move_lattice"}
    # the run's state box reaches the world's move range (y up to 0.36 m); the library's default moves stop at 0.35
    assert d.pop("state_high") == [0.55, 0.36, 2.4, 1.0, 1.0] and default["state_high"] == [0.55, 0.35, 2.4, 1.0, 1.0]
    assert {k: v for k, v in d.items() if k not in derived} == {
        k: v for k, v in default.items() if k in d and k not in derived
    }


def test_design_defaults():
    c = PlannerConfig()
    assert c.state_low == (0.05, 0.03, 0.0, 0.0, 0.0) and c.state_high == (0.55, 0.35, 2.4, 1.0, 1.0)
    assert c.move_x == (0.05, 0.55) and c.move_y == (0.03, 0.35)
    assert c.pour_theta == (0.0, 2.4) and c.pour_hold == (0.0, 1.5)
    assert (c.max_actions, c.goal_tol, c.spill_limit, c.n_candidates) == (6, 0.05, 0.02, 9)
    assert (c.beta, c.d_max) == (2.0, 0.07)


def test_overrides_and_omegaconf():
    from omegaconf import OmegaConf

    cfg = OmegaConf.create({"n_candidates": 3, "move_x": [0.1, 0.2]})
    c = PlannerConfig.from_dict(cfg, seed=7)
    assert c.n_candidates == 3 and c.move_x == (0.1, 0.2) and c.seed == 7


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(bogus=1), r"unknown planner config key\(s\) \['bogus'\]"),
        (dict(move_x=(0.5, 0.1)), r"move_x must be a finite range with low <= high"),
        (dict(pour_hold=(-1.0, 1.0)), r"pour_hold low end -1.0 is below 0.0"),
        (dict(p_move=1.5), r"p_move=1.5 outside allowed range \[0, 1\]"),
        (dict(max_actions=0), r"max_actions=0 must be >= 1"),
        (dict(goal_tol=0.0), r"goal_tol=0.0 must be > 0"),
        (dict(batch_min=64, batch_max=16), r"batch_min <= batch_max"),
        (dict(distance_weights=(0, 0, 0, 0)), r"distance_weights"),
        (dict(ompl_log_level="loud"), r"ompl_log_level='loud'"),
        (dict(torch_threads=None), r"torch_threads=None must be an integer >= 1, or 0 to leave torch's setting alone"),
        (dict(torch_threads=-1), r"torch_threads=-1 must be an integer >= 1, or 0"),
        (dict(problems={"goal": (0.2, 1.2)}), r"unknown planner config key\(s\) \['problems'\]"),
        (dict(move_y=(0.03, 0.4)), r"move_y=\[0.03, 0.4\] reaches outside the state bounds of y \[0.03, 0.35\]"),
        (dict(pour_theta=(0.0, 2.5)), r"pour_theta=\[0.0, 2.5\] reaches outside the state bounds of theta"),
        (dict(move_lattice=-0.01), r"move_lattice=-0.01: allowed 0 \(continuous move targets\) or a spacing > 0 m"),
        (dict(move_lattice="x"), r"move_lattice='x': allowed 0"),
        (
            dict(move_lattice=0.01, move_x=(0.053, 0.057)),
            r"move_x=\[0.053, 0.057\] holds no multiple of move_lattice=0.01",
        ),
    ],
)
def test_bad_config_values(kw, match):
    with pytest.raises(ValueError, match=match):
        PlannerConfig.from_dict(kw)


def test_action_sampler_ranges_and_reproducibility():
    c = PlannerConfig()
    s = ActionSampler(c)
    a = s.sample(4000, np.random.default_rng(0))
    assert a.shape == (4000, 3)
    np.testing.assert_array_equal(a, s.sample(4000, np.random.default_rng(0)))
    assert set(np.unique(a[:, 0])) == {0.0, 1.0}
    assert abs((a[:, 0] == 0).mean() - c.p_move) < 0.05
    mv, po = a[a[:, 0] == 0], a[a[:, 0] == 1]
    assert mv[:, 1].min() >= 0.05 and mv[:, 1].max() <= 0.55 and mv[:, 2].min() >= 0.03 and mv[:, 2].max() <= 0.35
    assert po[:, 1].min() >= 0.0 and po[:, 1].max() <= 2.4 and po[:, 2].min() >= 0.0 and po[:, 2].max() <= 1.5
    # covers the ranges (not stuck in a corner)
    assert mv[:, 1].max() - mv[:, 1].min() > 0.45 and po[:, 2].max() - po[:, 2].min() > 1.4
    assert s.contains(a).all()
    assert not s.contains([[1, 3.0, 0.5], [2, 0.1, 0.1], [0, 0.6, 0.1]]).any()
    only_pour = ActionSampler(c.replace(p_move=0.0)).sample(50, np.random.default_rng(1))
    assert (only_pour[:, 0] == 1).all()
    assert s.sample(0, np.random.default_rng(0)).shape == (0, 3)


def test_action_sampler_puts_moves_on_the_worlds_lattice():
    """With move_lattice the sampler proposes the move the world executes (the nearest lattice point);
    pours are untouched, and the random stream is the same as without a lattice."""
    c = PlannerConfig(move_x=(0.053, 0.55), move_y=(0.03, 0.35))
    free = ActionSampler(c).sample(2000, np.random.default_rng(3))
    on = ActionSampler(c.replace(move_lattice=0.01)).sample(2000, np.random.default_rng(3))
    mv = on[:, 0] == 0
    np.testing.assert_array_equal(on[~mv], free[~mv])
    np.testing.assert_allclose(on[mv, 1:], np.round(on[mv, 1:] / 0.01) * 0.01, atol=1e-12)
    # the nearest lattice point, moved inside the range: x in [0.06, 0.55], y in [0.03, 0.35]
    want = np.clip(np.round(free[mv, 1:] / 0.01) * 0.01, [0.06, 0.03], [0.55, 0.35])
    np.testing.assert_allclose(on[mv, 1:], want, rtol=0, atol=1e-12)
    assert on[mv, 1].min() >= 0.06 - 1e-12 and ActionSampler(c.replace(move_lattice=0.01)).contains(on).all()


def test_features_and_goal_helpers_numpy_and_torch():
    s = np.array([[0.2, 0.1, 0.0, 0.45, 0.54], [0.2, 0.1, 0.0, 0.40, 0.50]])
    a = np.array([[1, 1.0, 0.5], [0, 0.3, 0.2]])
    X = features(s, a)
    assert X.shape == (2, 8)
    s2, a2 = split_features(X)
    np.testing.assert_array_equal(s2, s)
    np.testing.assert_array_equal(a2, a)
    Xt = features(torch.tensor(s), torch.tensor(a))
    assert isinstance(Xt, torch.Tensor) and Xt.shape == (2, 8)
    np.testing.assert_allclose(spill(s), [0.01, 0.10])
    np.testing.assert_array_equal(goal_reached(s, 0.5, 0.05), [True, False])  # 2nd: spill 0.1
    assert goal_reached(s[0], 0.5, 0.05) is True
    assert goal_reached(s[0], 0.5, 0.03) is False
    assert goal_reached(s[1], 0.5, 0.05, max_spill=0.2) is True
    assert goal_reached(torch.tensor(s[0]), 0.5, 0.05) is True
    d = goal_distance(s, 0.5, 0.05)
    assert d[0] == 0.0 and d[1] == pytest.approx(0.08)
    np.testing.assert_array_equal(skill_ids(a), [1, 0])
    assert describe_action(a[0]) == "pour(theta=1.000, hold=0.500)"
    with pytest.raises(ValueError, match="last dimension 5"):
        features(np.zeros((2, 4)), a)
    with pytest.raises(ValueError, match="batch shapes differ"):
        features(s, a[:1])


def test_standins_follow_the_protocols():
    robot = ToyPointRobot()
    for m in (AnalyticPouringModel(), StandInMLPDynamics(), robot):
        assert isinstance(m, DynamicsModel)
    for m in (StandInGPMDE(), ToyBoxMDE(robot)):
        assert isinstance(m, DeviationEstimator)
