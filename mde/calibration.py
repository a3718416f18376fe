"""Calibration of an MDE's Gaussian predictions on held-out data.

The planner trusts ``mu + beta * sigma < d_max`` with beta = 2 at test time, i.e. it relies on the
predictive std meaning what a Gaussian std means. This module measures that: coverage of central
intervals (50/80/95% and a fine grid for the reliability plot) and the mean Gaussian negative log
likelihood, against the held-out labels as the MDE fits them (capped at ``label_max`` if it caps).

    python -m mde.calibration --model mde.pt --data heldout.pt --out results/calibration

``--data`` is a ``torch.save``'d dict with ``X`` (n x d) and ``y`` (n). Writes
``calibration.json`` and ``reliability.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any, Sequence

import torch
from torch import Tensor

import safeio

from .grouped import load

REPORT_LEVELS = (0.5, 0.8, 0.95)
#: Levels of the reliability curve (expected coverage on the x axis).
CURVE_LEVELS = tuple(round(0.05 * k, 2) for k in range(1, 20)) + (0.99,)


def _normal_icdf(p: Tensor) -> Tensor:
    return math.sqrt(2.0) * torch.erfinv(2.0 * p - 1.0)


def gaussian_calibration(
    mean: Tensor,
    std: Tensor,
    y: Tensor,
    levels: Sequence[float] = REPORT_LEVELS,
    curve_levels: Sequence[float] = CURVE_LEVELS,
) -> dict[str, Any]:
    """Calibration numbers of Gaussian predictions ``N(mean, std^2)`` for observations ``y``.

    Coverage of the central ``p`` interval is the fraction of ``|y - mean| <= z_{(1+p)/2} std``.
    NLL is the mean of ``0.5 log(2 pi std^2) + (y - mean)^2 / (2 std^2)``.
    """
    mean, std, y = (torch.as_tensor(t, dtype=torch.float64).reshape(-1) for t in (mean, std, y))
    if not (mean.shape == std.shape == y.shape):
        raise ValueError(f"mean {tuple(mean.shape)}, std {tuple(std.shape)} and y {tuple(y.shape)} differ in length")
    if y.numel() == 0:
        raise ValueError("calibration needs at least one held-out point")
    for name, t in (("mean", mean), ("std", std), ("y", y)):
        if not torch.isfinite(t).all():
            raise ValueError(f"{name} contains NaN or inf")
    if (std <= 0).any():
        raise ValueError("std must be > 0 everywhere")
    z = (y - mean).abs() / std

    def coverage(p: float) -> float:
        if not 0.0 < p < 1.0:
            raise ValueError(f"coverage levels must lie in (0, 1), got {p}")
        return float((z <= _normal_icdf(torch.tensor(0.5 + 0.5 * p, dtype=torch.float64))).double().mean())

    nll = 0.5 * torch.log(2 * math.pi * std**2) + 0.5 * z**2
    return {
        "n": int(y.numel()),
        "coverage": {f"{p:g}": coverage(p) for p in levels},
        "nll": float(nll.mean()),
        "rmse": float(torch.sqrt(((y - mean) ** 2).mean())),
        "mean_std": float(std.mean()),
        "reliability": {
            "expected": [float(p) for p in curve_levels],
            "observed": [coverage(p) for p in curve_levels],
        },
    }


def fitted_labels(model: Any, y: Any) -> Tensor:
    """``y`` as ``model`` fits labels: capped at its ``config.label_max`` where it has one.

    An MDE fitted on capped labels predicts the capped deviation (the precondition's decision,
    mu + beta sigma < d_max, is the same for any label above the cap), so a raw held-out label above
    the cap would lie outside every interval by construction and say nothing about calibration.
    """
    y = torch.as_tensor(y)
    cap = getattr(getattr(model, "config", None), "label_max", None)
    return y if cap is None else y.clamp(max=float(cap))


def calibration_report(model: Any, X: Any, y: Any, as_fitted: bool = True, **kwargs: Any) -> dict[str, Any]:
    """Calibration of ``model.predict(X) -> (mean, std)`` against held-out labels ``y``.

    ``model`` is any object with that method (an MDE, or a stand-in with known predictions).
    ``as_fitted``: compare with the labels as the model fits them (:func:`fitted_labels`); False
    compares with the raw labels.
    """
    mean, std = model.predict(torch.as_tensor(X))
    target = fitted_labels(model, y) if as_fitted else torch.as_tensor(y)
    return gaussian_calibration(mean, std, target, **kwargs)


def cross_validate(make_mde: Any, X: Any, y: Any, groups: Any, folds: int = 5, seed: int = 0) -> tuple[Tensor, Tensor]:
    """Out-of-sample mean and std at every row: K-fold over whole ``groups`` (e.g. trajectory ids,
    so that no step of a held-out trajectory is seen in fitting). ``make_mde()`` gives a fresh MDE.

    In-sample predictions flatter a GP that interpolates its noise; what the planner meets on new
    problems is closer to these.
    """
    X, y, groups = torch.as_tensor(X), torch.as_tensor(y), torch.as_tensor(groups)
    ids = torch.unique(groups)
    if folds < 2 or len(ids) < folds:
        raise ValueError(f"folds={folds}: need 2 <= folds <= number of groups ({len(ids)})")
    ids = ids[torch.randperm(len(ids), generator=torch.Generator().manual_seed(seed))]
    mean = torch.empty(len(y), dtype=torch.float64)
    std = torch.empty(len(y), dtype=torch.float64)
    for k in range(folds):
        held = torch.isin(groups, ids[k::folds])
        m, s = make_mde().fit(X[~held], y[~held]).predict(X[held])
        mean[held], std[held] = m.double(), s.double()
    return mean, std


def reliability_plot(report: dict[str, Any], path: str | Path, title: str = "MDE reliability") -> Path:
    """Expected vs observed coverage of central intervals (diagonal = perfectly calibrated).

    Drawn on an Agg canvas without pyplot, so it neither needs a display nor changes the
    process-wide matplotlib backend.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # only to plot: about half a second to import
    from matplotlib.figure import Figure

    expected = report["reliability"]["expected"]
    observed = report["reliability"]["observed"]
    fig = Figure(figsize=(4.2, 4.2), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.plot([0, 1], [0, 1], color="0.6", linestyle="--", label="ideal")
    ax.plot(expected, observed, marker="o", markersize=3, label="MDE")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_xlabel("expected coverage of central interval")
    ax.set_ylabel("observed coverage")
    cov = ", ".join(f"{k}: {v:.2f}" for k, v in report["coverage"].items())
    ax.set_title(f"{title}\nNLL {report['nll']:.3f}, n={report['n']}\n{cov}", fontsize=8)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    return safeio.save_figure(fig, path)


def load_heldout(path: str | Path) -> tuple[Tensor, Tensor]:
    """Read a ``.pt`` holding a dict with ``X`` and ``y``."""
    data = torch.load(Path(path), map_location="cpu", weights_only=True)
    if not isinstance(data, dict) or "X" not in data or "y" not in data:
        raise ValueError(f"{path} must hold a dict with keys 'X' and 'y'")
    return torch.as_tensor(data["X"]), torch.as_tensor(data["y"])


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m mde.calibration", description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, help="saved MDE (.pt): GPMDE or GroupedMDE")
    parser.add_argument("--data", required=True, help="held-out data: .pt with a dict {'X': n x d, 'y': n}")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument(
        "--raw-labels",
        action="store_true",
        help="compare with the raw labels, not capped at the model's label_max as it fits them",
    )
    args = parser.parse_args(argv)
    mde = load(args.model)
    X, y = load_heldout(args.data)
    report = calibration_report(mde, X, y, as_fitted=not args.raw_labels)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    safeio.write_json(out / "calibration.json", report, indent=2)
    reliability_plot(report, out / "reliability.png")
    cov = "  ".join(f"{float(k) * 100:.0f}%: {v:.3f}" for k, v in report["coverage"].items())
    print(f"n={report['n']}  coverage  {cov}  NLL={report['nll']:.4f}  RMSE={report['rmse']:.4g}")
    print(f"wrote {out / 'calibration.json'} and {out / 'reliability.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
