"""Stand-in dynamics / MDE used by tests and the bench, and a quick smoke run of the bench."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from planner import PlannerConfig, goal_reached
from tests.doubles.standins import (
    AnalyticPouringModel,
    StandInGPMDE,
    StandInMLPDynamics,
    plant_deviation,
    synthetic_deviation_dataset,
)


def _pour_from(x, y, theta, hold, v=1.0):
    m = AnalyticPouringModel()
    s = torch.tensor([[x, y, 0.0, v, 0.0]], dtype=torch.float64)
    a = torch.tensor([[1.0, theta, hold]], dtype=torch.float64)
    return m.predict(s, a)[0].numpy()


def test_move_sets_pose_and_keeps_water():
    m = AnalyticPouringModel()
    s = torch.tensor([[0.4, 0.2, 0.0, 0.7, 0.2]], dtype=torch.float64)
    out = m.predict(s, torch.tensor([[0.0, 0.25, 0.05]], dtype=torch.float64))[0].numpy()
    np.testing.assert_allclose(out, [0.25, 0.05, 0.0, 0.7, 0.2])


def test_pour_physics_is_plausible():
    # upright or barely tilted: nothing leaves the full cup beyond its capacity
    np.testing.assert_allclose(_pour_from(0.25, 0.1, 0.0, 1.0)[3:], [1.0, 0.0])
    # tilted over the target cup: water lands in it, water is conserved, cup returns upright
    s = _pour_from(0.25, 0.1, 1.0, 1.5)
    assert s[2] == 0.0 and 0.3 < s[4] < 0.9 and abs(s[3] + s[4] - 1.0) < 1e-3
    # same pour far from the target cup: everything that leaves is spilled
    s = _pour_from(0.5, 0.1, 1.0, 1.5)
    assert s[4] == pytest.approx(0.0, abs=1e-9) and s[3] < 0.7
    # more tilt or a longer hold never pours less
    amounts = [1 - _pour_from(0.25, 0.1, th, 1.0)[3] for th in (0.3, 0.6, 0.9, 1.2)]
    assert np.all(np.diff(amounts) >= 0) and amounts[-1] > 0.9
    assert 1 - _pour_from(0.25, 0.1, 0.8, 0.0)[3] < 1 - _pour_from(0.25, 0.1, 0.8, 1.5)[3]
    # a goal state is reachable in one pour from a good spot
    assert goal_reached(_pour_from(0.25, 0.1, 1.3, 1.5), 0.95, 0.05)


def test_mlp_standin_is_close_to_analytic_and_seeded():
    rng = np.random.default_rng(0)
    s = torch.tensor(np.tile([0.4, 0.2, 0.0, 1.0, 0.0], (64, 1)), dtype=torch.float32)
    a = torch.tensor(
        np.c_[rng.integers(0, 2, 64), rng.uniform(0.05, 0.5, 64), rng.uniform(0.05, 0.3, 64)], dtype=torch.float32
    )
    m1, m2 = StandInMLPDynamics(seed=1), StandInMLPDynamics(seed=1)
    out = m1.predict(s, a)
    torch.testing.assert_close(out, m2.predict(s, a))
    ref = AnalyticPouringModel().predict(s, a)
    assert 0 < (out - ref).abs().max() < 0.01
    assert sum(p.numel() for p in m1.net.parameters()) == 8 * 128 + 128 + 128 * 128 + 128 + 128 * 5 + 5


def test_gp_standin_fits_synthetic_deviation():
    X, d = synthetic_deviation_dataset(400, np.random.default_rng(0))
    assert X.shape == (400, 8) and d.shape == (400,) and (d >= 0).all()
    assert 0.05 < (plant_deviation(X) > 0.07).mean() < 0.5  # the "plant" region is visited
    gp = StandInGPMDE(fit_iters=60, fit_subset=200).fit(X, d)
    mean_in, _ = gp.predict(torch.as_tensor(X))
    assert float(np.sqrt(np.mean((mean_in.numpy() - d) ** 2))) < 0.3 * d.std()
    Xq, _ = synthetic_deviation_dataset(400, np.random.default_rng(1))
    mean, std = gp.predict(torch.as_tensor(Xq))
    assert mean.shape == (400,) and std.shape == (400,) and (std > 0).all()
    high = plant_deviation(Xq) > 0.07
    assert mean.numpy()[high].mean() > 2 * mean.numpy()[~high].mean()  # tells the plant apart
    # far from all data the prediction reverts to the prior: zero deviation, wide std
    far = torch.full((1, 8), 50.0, dtype=torch.float64)
    m, s = gp.predict(far)
    assert abs(float(m)) < 1e-6 and float(s) > std.median()
    with pytest.raises(RuntimeError, match="before fit"):
        StandInGPMDE().predict(far)


def test_bench_quick_smoke(tmp_path, capsys):
    from benchmarks import planner as bench

    out = tmp_path / "bench.json"
    rc = bench.main(
        [
            "--problems",
            "2",
            "--mde",
            "standin",
            "--mde-points",
            "100",
            "--candidates",
            "2",
            "--candidate-problems",
            "1",
            "--unbatched-problems",
            "1",
            "--throughput-seconds",
            "0.02",
            "--time-budget",
            "0.2",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    text = capsys.readouterr().out
    assert "propagations/s" in text and "median plan time" in text and "TARGET" in text
    r = json.loads(out.read_text())
    assert r["planning"]["runs"] == 2 and r["planning"]["propagations"] > 0
    assert r["mde"]["kind"].startswith("tests.doubles.standins.StandInGPMDE")
    assert set(r["targets"]) == {"propagations_per_s", "median_plan_s"}
    assert PlannerConfig.from_dict(r["config"]).n_candidates == 2
