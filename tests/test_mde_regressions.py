"""Regressions found on simulator data."""

import warnings
from pathlib import Path

import torch

from mde import HeteroscedasticGPMDE

DATA = Path(__file__).parent / "data" / "mde_abnormal_line_search.pt"


def test_fit_survives_abnormal_line_search_stops():
    """On these 60 transitions L-BFGS-B stops with an "ABNORMAL" line search; that used to count as
    a failed fit and left the MDE at its prior."""
    d = torch.load(DATA)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mde = HeteroscedasticGPMDE(num_threads=1).fit(d["X"], d["y"])
    assert mde.is_fitted
    assert not [w for w in caught if "keeping the" in str(w.message)]
    mean, std = mde.predict(d["X"])
    assert torch.isfinite(mean).all() and (std > 0).all()
    assert (mean - d["y"]).abs().median() < 0.05  # it learned the data, not the prior (mean 0, std 1)
