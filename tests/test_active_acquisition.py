"""Acquisition functions against values computed by hand from a known posterior."""


import pytest
import torch
from botorch.models.model import Model
from botorch.posteriors.gpytorch import GPyTorchPosterior
from gpytorch.distributions import MultivariateNormal

from active.acquisition import DiscountedMaxUCB, TrajectoryStraddle, TrajectoryVariance


class KnownPosterior(Model):
    """mean = X[..., 0], variance = X[..., 1]: a posterior we can compute by hand."""

    num_outputs = 1

    def posterior(self, X, output_indices=None, observation_noise=False, posterior_transform=None):
        mean = X[..., 0]
        cov = torch.diag_embed(X[..., 1])
        return GPyTorchPosterior(MultivariateNormal(mean, cov))


def traj(*steps):
    return torch.tensor([[list(s) for s in steps]], dtype=torch.float64)


# two 3-step trajectories: (mean, variance) per step
A = traj((0.02, 0.0004), (0.05, 0.0025), (0.03, 0.0001))
B = traj((0.01, 0.0100), (0.02, 0.0001), (0.06, 0.0009))


def test_paper_acquisition_by_hand():
    model = KnownPosterior()
    acq = DiscountedMaxUCB(model, c=0.1, gamma=0.9)
    # alpha(A) = max(0.02 + 0.1*0.02, 0.9*(0.05 + 0.1*0.05), 0.81*(0.03 + 0.1*0.01))
    alpha_a = max(0.022, 0.9 * 0.055, 0.81 * 0.031)
    alpha_b = max(0.01 + 0.1 * 0.1, 0.9 * (0.02 + 0.001), 0.81 * (0.06 + 0.003))
    assert acq(A).item() == pytest.approx(-alpha_a)
    assert acq(B).item() == pytest.approx(-alpha_b)
    both = torch.cat([A, B])
    assert torch.allclose(acq(both), torch.tensor([-alpha_a, -alpha_b], dtype=torch.float64))


def test_choice_rule_depends_on_c():
    """Which candidate each c picks (the chosen one is the argmax of forward = argmin alpha)."""
    model = KnownPosterior()
    low_mean_certain = traj((0.03, 1e-6), (0.03, 1e-6))  # alpha ~ 0.03 for any small c
    higher_mean_uncertain = traj((0.035, 0.04), (0.01, 1e-6))  # sigma_0 = 0.2
    cands = torch.cat([low_mean_certain, higher_mean_uncertain])
    pick = lambda **kw: DiscountedMaxUCB(model, **kw)(cands).argmax().item()  # noqa: E731
    # Eq. 1, mu + c sigma: alpha_1 = max(0.035 + 0.2 c, 0.01)
    assert pick(c=0.0) == 0  # 0.030 < 0.035
    assert pick(c=0.1) == 0  # 0.030 < 0.055
    assert pick(c=-0.1) == 1  # 0.015 < 0.030: Eq. 1 with c < 0 rewards uncertainty
    # LCB form, mu - c sigma: the paper's naming (higher c, more exploration)
    assert pick(c=-0.1, form="lcb") == 0
    assert pick(c=0.1, form="lcb") == 1
    with pytest.raises(ValueError, match="acquisition.form"):
        DiscountedMaxUCB(model, form="ucb")


def test_straddle_and_variance_by_hand():
    model = KnownPosterior()
    st = TrajectoryStraddle(model, d_max=0.07, kappa=1.96)
    exp_a = max(1.96 * 0.02 - 0.05, 1.96 * 0.05 - 0.02, 1.96 * 0.01 - 0.04)
    assert st(A).item() == pytest.approx(exp_a)
    var = TrajectoryVariance(model, gamma=0.5)
    assert var(B).item() == pytest.approx(max(0.01, 0.5 * 0.0001, 0.25 * 0.0009))


@pytest.mark.parametrize("gamma", [0.0, -0.5, 1.5])
def test_gamma_outside_range_is_rejected(gamma):
    with pytest.raises(ValueError, match=r"gamma .* allowed \(0, 1\]"):
        DiscountedMaxUCB(KnownPosterior(), gamma=gamma)


def test_straddle_needs_positive_threshold():
    with pytest.raises(ValueError, match="d_max"):
        TrajectoryStraddle(KnownPosterior(), d_max=0.0)


def test_user_acquisition_plugs_in_by_target(tmp_path, monkeypatch):
    """The README's example: a user's class named by `acquisition._target_`, no edit of our code."""
    from active.experiment import ExperimentConfig
    from active.loop import acquisition_factory

    (tmp_path / "my_acq.py").write_text(
        "from active.acquisition import TrajectoryAcquisition\n"
        "class WorstStepStd(TrajectoryAcquisition):\n"
        "    minimise = True\n"
        "    def step_score(self, mean, std):\n"
        "        return std\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    make = acquisition_factory({"_target_": "my_acq.WorstStepStd", "gamma": 1.0}, ExperimentConfig())
    acq = make(KnownPosterior(), 0.1)
    assert acq(torch.cat([A, B])).tolist() == pytest.approx([-0.05, -0.1])  # -max_t sigma_t
