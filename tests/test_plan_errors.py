"""The perfect-model bound of ``benchmarks.plan_errors``: the goal-band probability it averages."""

import numpy as np
import pytest

from benchmarks.plan_errors import perfect_model_success


def test_perfect_model_bound_follows_the_normal_band_probability():
    # a plan aimed at the goal: P(|e| <= tol) = 2 Phi(tol / s) - 1 (0.6827 at tol = s)
    assert perfect_model_success([0.0], 0.05, 0.05) == pytest.approx(0.682689, abs=1e-6)
    # aimed at the band's edge: half of the outcomes land inside (less the far tail)
    assert perfect_model_success([0.05], 0.05, 0.01) == pytest.approx(0.5, abs=1e-6)
    # no scatter left: every plan inside the band succeeds, every plan outside fails
    assert perfect_model_success([0.0, 0.049, -0.03, 0.2], 0.05, 1e-6) == pytest.approx(0.75)
    # less scatter never hurts plans inside the band, and the mean is over plans
    offs = np.linspace(-0.05, 0.05, 11)
    assert perfect_model_success(offs, 0.05, 0.035) < perfect_model_success(offs, 0.05, 0.017) < 1.0
