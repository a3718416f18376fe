"""Calibration report on cases with known answers, the reliability plot and the command."""

from __future__ import annotations

import json
import math

import pytest
import torch

from mde import GPMDE, calibration_report
from mde.calibration import gaussian_calibration, main, reliability_plot


class KnownGaussian:
    """Stand-in model with known predictive N(mean(x), std(x)^2) (std optionally mis-scaled)."""

    def __init__(self, std_scale: float = 1.0) -> None:
        self.std_scale = std_scale

    @staticmethod
    def truth(X: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return 1.0 + X[:, 0], 0.1 + X[:, 1]

    def predict(self, X: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mean, std = self.truth(X)
        return mean, std * self.std_scale


def _sample(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    X = torch.rand(n, 2, generator=g, dtype=torch.float64)
    mean, std = KnownGaussian.truth(X)
    return X, mean + std * torch.randn(n, generator=g, dtype=torch.float64)


def test_calibrated_model_on_data_drawn_from_it():
    n = 20_000
    X, y = _sample(n, seed=0)
    rep = calibration_report(KnownGaussian(), X, y)
    for level, cov in rep["coverage"].items():
        p = float(level)
        assert abs(cov - p) < 4 * math.sqrt(p * (1 - p) / n), (level, cov)
    _, std = KnownGaussian.truth(X)
    expected_nll = float((0.5 * torch.log(2 * math.pi * std**2)).mean()) + 0.5
    assert rep["nll"] == pytest.approx(expected_nll, abs=0.03)
    assert rep["n"] == n and len(rep["reliability"]["expected"]) == len(rep["reliability"]["observed"])


def test_exact_quantile_construction():
    """y at the (i + 1/2)/N quantiles of each prediction: coverage of p is p to within 1/N."""
    N = 1000
    mean = torch.linspace(-1, 1, N, dtype=torch.float64)
    std = torch.linspace(0.1, 2.0, N, dtype=torch.float64)
    u = (torch.arange(N, dtype=torch.float64) + 0.5) / N
    y = mean + std * math.sqrt(2.0) * torch.erfinv(2 * u - 1)
    rep = gaussian_calibration(mean, std, y, levels=(0.5, 0.8, 0.95, 0.99))
    for level, cov in rep["coverage"].items():
        assert abs(cov - float(level)) <= 1.0 / N + 1e-12
    for e, o in zip(rep["reliability"]["expected"], rep["reliability"]["observed"]):
        assert abs(o - e) <= 1.0 / N + 1e-12


def test_overdispersed_predictions_overcover():
    X, y = _sample(5000, seed=1)
    wide = calibration_report(KnownGaussian(std_scale=2.0), X, y)
    narrow = calibration_report(KnownGaussian(std_scale=0.5), X, y)
    assert wide["coverage"]["0.5"] > 0.75 and narrow["coverage"]["0.95"] < 0.75
    assert all(o > e for e, o in zip(wide["reliability"]["expected"], wide["reliability"]["observed"]))
    exact = calibration_report(KnownGaussian(), X, y)
    assert exact["nll"] < wide["nll"] and exact["nll"] < narrow["nll"]


def test_bad_inputs():
    with pytest.raises(ValueError, match="differ in length"):
        gaussian_calibration(torch.zeros(3), torch.ones(3), torch.zeros(4))
    with pytest.raises(ValueError, match="std must be > 0"):
        gaussian_calibration(torch.zeros(2), torch.tensor([1.0, 0.0]), torch.zeros(2))
    with pytest.raises(ValueError, match="NaN or inf"):
        gaussian_calibration(torch.zeros(2), torch.ones(2), torch.tensor([0.0, float("nan")]))


def test_reliability_plot_is_a_png(tmp_path):
    X, y = _sample(500, seed=2)
    path = reliability_plot(calibration_report(KnownGaussian(), X, y), tmp_path / "r.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_command_writes_report_and_plot(tmp_path, capsys):
    g = torch.Generator().manual_seed(3)
    X = torch.rand(80, 2, generator=g, dtype=torch.float64)
    y = (0.5 + 0.3 * X[:, 0] + 0.05 * torch.randn(80, generator=g, dtype=torch.float64)).clamp_min(0)
    mde = GPMDE(heteroscedastic=False, num_threads=1).fit(X[:50], y[:50])
    mde.save(tmp_path / "mde.pt")
    torch.save({"X": X[50:], "y": y[50:]}, tmp_path / "heldout.pt")
    argv = ["--model", str(tmp_path / "mde.pt"), "--data", str(tmp_path / "heldout.pt"), "--out", str(tmp_path / "cal")]
    assert main(argv) == 0
    report = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert set(report["coverage"]) == {"0.5", "0.8", "0.95"} and report["n"] == 30
    direct = calibration_report(mde, X[50:], y[50:])
    assert report["coverage"] == pytest.approx(direct["coverage"]) and report["nll"] == pytest.approx(direct["nll"])
    assert (tmp_path / "cal" / "reliability.png").stat().st_size > 1000
    assert "coverage" in capsys.readouterr().out


class CappedGaussian(KnownGaussian):
    """A stand-in MDE fitted on labels capped at 1.15: it predicts the capped deviation."""

    class config:  # noqa: N801 - the attribute an MDE's configuration is read from
        label_max = 1.15


def test_labels_above_the_cap_are_compared_as_fitted():
    """A raw label above the model's label_max lies outside every interval of a model that predicts capped
    labels; as fitted (capped) it is the cap, inside the interval when the prediction is near the cap."""
    X = torch.zeros(4, 2, dtype=torch.float64)  # mean 1.0, std 0.1: the 95 % interval is 1.0 +- 0.196
    y = torch.tensor([1.0, 1.1, 5.0, 9.0], dtype=torch.float64)
    as_fitted = calibration_report(CappedGaussian(), X, y)
    raw = calibration_report(CappedGaussian(), X, y, as_fitted=False)
    assert as_fitted["coverage"]["0.95"] == 1.0 and raw["coverage"]["0.95"] == 0.5
    assert as_fitted["nll"] < raw["nll"]
    # a model without a cap is compared with the raw labels either way
    assert calibration_report(KnownGaussian(), X, y)["coverage"] == raw["coverage"]
