"""Acquisition functions against values computed by hand from a known posterior."""

import pytest
import torch
from botorch.models.model import Model
from botorch.posteriors.gpytorch import GPyTorchPosterior
from gpytorch.distributions import MultivariateNormal

from active.acquisition import (
    DiscountedMaxLCB,
    DiscountedMaxUCB,
    TrajectoryStraddle,
    TrajectoryThompson,
    TrajectoryVariance,
)


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
    # LCB reading, mu - c sigma (a subclass): the paper's naming (higher c, more exploration)
    pick_lcb = lambda **kw: DiscountedMaxLCB(model, **kw)(cands).argmax().item()  # noqa: E731
    assert pick_lcb(c=-0.1) == 0
    assert pick_lcb(c=0.1) == 1


def test_a_single_trajectory_is_a_batch_of_one():
    """BoTorch's t-batch convention (t_batch_mode_transform): T x d is one trajectory, batch x T x d many."""
    acq = DiscountedMaxUCB(KnownPosterior(), c=0.1, gamma=0.9)
    assert acq(A[0]).shape == (1,) and acq(A[0]).item() == pytest.approx(acq(A).item())
    assert acq(torch.cat([A, B])).shape == (2,)


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


def test_thompson_draws_are_reproducible_and_follow_the_posterior():
    """One joint draw per trajectory, seeded by its features and the seed: the same trajectory gets the same score
    alone or among others; over many trajectories the drawn steps have the posterior's mean and std; the
    candidate with the best draw is chosen (forward = -score)."""
    acq = TrajectoryThompson(KnownPosterior(), seed=3)
    both = torch.cat([A, B])
    assert torch.equal(acq(both), torch.cat([acq(A), acq(B)]))
    assert torch.equal(acq(A), TrajectoryThompson(KnownPosterior(), seed=3)(A))
    assert not torch.equal(acq(A), TrajectoryThompson(KnownPosterior(), seed=4)(A))
    # one-step trajectories at mean 0.05, std 0.02, each with its own (tiny) feature offset: a distinct draw each
    n = 4000
    X = torch.stack(
        [
            torch.full((n,), 0.05, dtype=torch.float64),
            torch.full((n,), 0.0004, dtype=torch.float64),
            torch.arange(n, dtype=torch.float64),
        ],
        dim=-1,
    ).unsqueeze(1)
    draws = -acq(X)
    assert abs(float(draws.mean()) - 0.05) < 4 * 0.02 / n**0.5
    assert float(draws.std()) == pytest.approx(0.02, rel=0.05)
    # a certain low trajectory against an uncertain one of higher mean: alpha always picks the first, Thompson the
    # second in about the share of draws below 0.03 (P(N(0.035, 0.05^2) < 0.03) = 0.46)
    certain, uncertain = traj((0.03, 1e-12, 0.0)), traj((0.035, 0.0025, 0.0))
    picks = [
        int(TrajectoryThompson(KnownPosterior(), seed=k)(torch.cat([certain, uncertain])).argmax()) for k in range(400)
    ]
    assert 0.38 < sum(picks) / len(picks) < 0.54
    assert int(DiscountedMaxUCB(KnownPosterior(), c=0.0)(torch.cat([certain, uncertain])).argmax()) == 0


def test_straddle_needs_positive_threshold():
    with pytest.raises(ValueError, match="d_max"):
        TrajectoryStraddle(KnownPosterior(), d_max=0.0)


def test_user_acquisition_plugs_in_by_target(tmp_path, monkeypatch):
    """The README's example: a user's class named by `acquisition._target_`, no edit of our code."""
    from active.acquisition_factory import acquisition_factory
    from active.experiment import ExperimentConfig

    (tmp_path / "my_acq.py").write_text(
        "from active.acquisition import TrajectoryAcquisition\n"
        "class WorstStepStd(TrajectoryAcquisition):\n"
        "    minimise = True\n"
        "    def step_score(self, mean, std):\n"
        "        return std\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    from active.methods import build_method
    from active.run import compose_config

    # README: a new method beside the others, with the user's acquisition as its own
    overrides = [
        "+methods.mine._target_=active.methods.ActiveChoice",
        "+methods.mine.acquisition._target_=my_acq.WorstStepStd",
        "method=mine",
        "experiment=tiny",
        f"dynamics.cache_root={tmp_path / 'cache'}",
    ]
    cfg = compose_config(overrides)
    from active.run import prepare_run

    spec = prepare_run(cfg, tmp_path / "out")  # every check a run makes before compute passes
    assert spec.exp.methods == ("mine",)
    method = build_method("mine", cfg["methods"])
    acq = spec.make_acq(KnownPosterior(), method.acquisition)
    assert type(acq).__name__ == "WorstStepStd"
    assert acq(torch.cat([A, B])).tolist() == pytest.approx([-0.05, -0.1])  # -max_t sigma_t
    # or in place of the configured acquisition (every method without its own spec then uses it)
    cfg = compose_config(["acquisition._target_=my_acq.WorstStepStd", "method=active_balanced"])
    make = acquisition_factory(cfg["acquisition"], ExperimentConfig())
    acq = make(KnownPosterior(), build_method("active_balanced").acquisition)  # c = 0.1: not accepted, not passed
    assert type(acq).__name__ == "WorstStepStd"


@pytest.mark.parametrize(
    "group,cls",
    [
        ("alpha", DiscountedMaxUCB),
        ("lcb", DiscountedMaxLCB),
        ("straddle", TrajectoryStraddle),
        ("variance", TrajectoryVariance),
        ("thompson", TrajectoryThompson),
    ],
)
def test_acquisition_group_builds_each_option_with_the_methods_c(group, cls):
    """configs/acquisition/<group>.yaml is a _partial_ spec; the loop completes it with the model, the
    method's c (where accepted) and d_max = experiment.d_max (where accepted)."""
    from active.acquisition_factory import acquisition_factory
    from active.experiment import ExperimentConfig
    from active.methods import build_method
    from active.run import compose_config

    cfg = compose_config([f"acquisition={group}"])
    assert cfg["acquisition"]["_partial_"] is True
    make = acquisition_factory(cfg["acquisition"], ExperimentConfig(d_max=0.05))
    acq = make(KnownPosterior(), build_method("active_cautious").acquisition)
    assert type(acq) is cls
    if hasattr(acq, "c"):
        assert acq.c == -0.1
    if hasattr(acq, "d_max"):
        assert acq.d_max == 0.05


def test_default_acquisition_is_the_papers_alpha_and_methods_carry_c():
    from active.methods import METHODS, ActiveChoice, RandomActions, RandomPlan, build_method
    from active.run import compose_config

    assert compose_config([])["acquisition"] == {
        "_target_": "active.acquisition.DiscountedMaxUCB",
        "_partial_": True,
        "gamma": 1.0,
    }
    assert sorted(METHODS) == [
        "active_admission",
        "active_balanced",
        "active_cautious",
        "active_mean",
        "active_straddle",
        "active_thompson",
        "model_plan",
        "oracle",
        "random_actions",
        "random_plan",
    ]
    cs = {m: build_method(m).acquisition for m in METHODS}
    assert cs == {
        "random_actions": None,
        "random_plan": None,
        "model_plan": None,
        "oracle": None,  # a bound: it scores executed candidates, no acquisition
        "active_cautious": {"c": -0.1},
        "active_mean": {"c": 0.0},
        "active_balanced": {"c": 0.1},
        "active_straddle": {"_target_": "active.acquisition.TrajectoryStraddle", "kappa": 1.96, "gamma": 1.0},
        "active_thompson": {"_target_": "active.acquisition.TrajectoryThompson", "seed": 0, "gamma": 1.0},
        "active_admission": {"_target_": "active.acquisition.TrajectoryAdmissionGain"},
    }
    assert isinstance(build_method("random_actions"), RandomActions) and not build_method("random_actions").plans
    assert isinstance(build_method("random_plan"), RandomPlan)
    assert isinstance(build_method("active_mean"), ActiveChoice)


def test_a_method_with_its_own_acquisition_spec_ignores_the_configured_one():
    """active_straddle names acquisition._target_: one run can compare it with the paper's methods, which keep the
    configured acquisition (here the paper's alpha) and their c."""
    from active.acquisition_factory import acquisition_factory, check_method_acquisition
    from active.experiment import ExperimentConfig
    from active.methods import build_method
    from active.run import compose_config

    cfg = compose_config(["experiment.methods=[active_straddle,active_balanced]"])
    make = acquisition_factory(cfg["acquisition"], ExperimentConfig(d_max=0.05))
    for m in ("active_straddle", "active_balanced"):
        check_method_acquisition(m, build_method(m, cfg["methods"]), make)
    own = make(KnownPosterior(), build_method("active_straddle", cfg["methods"]).acquisition)
    assert type(own) is TrajectoryStraddle and own.kappa == 1.96 and own.d_max == 0.05  # d_max from the experiment
    # max_t (1.96 sigma_t - |mu_t - 0.05|) by hand, maximised
    want = max(1.96 * 0.02 - 0.03, 1.96 * 0.05 - 0.0, 1.96 * 0.01 - 0.02)
    assert own(A).item() == pytest.approx(want)
    paper = make(KnownPosterior(), build_method("active_balanced", cfg["methods"]).acquisition)
    assert type(paper) is DiscountedMaxUCB and paper.c == 0.1


@pytest.mark.parametrize(
    "override,match",
    [
        (
            "+methods.active_straddle.acquisition.c=0.1",
            r"methods.active_straddle.acquisition: \['c'\] is not a parameter "
            r"of active.acquisition.TrajectoryStraddle",
        ),
        (
            "methods.active_straddle.acquisition._target_=no_such.Acq",
            r"methods.active_straddle.acquisition._target_ = "
            r"'no_such.Acq' cannot be imported",
        ),
    ],
)
def test_a_methods_own_acquisition_spec_is_checked_before_compute(override, match):
    from active.acquisition_factory import acquisition_factory, check_method_acquisition
    from active.experiment import ExperimentConfig
    from active.methods import build_method
    from active.run import compose_config

    cfg = compose_config([override])
    make = acquisition_factory(cfg["acquisition"], ExperimentConfig())
    with pytest.raises(ValueError, match=match):
        check_method_acquisition("active_straddle", build_method("active_straddle", cfg["methods"]), make)


def test_an_acquisition_key_its_class_does_not_take_is_refused_before_compute():
    from active.acquisition_factory import acquisition_factory
    from active.experiment import ExperimentConfig

    with pytest.raises(
        ValueError,
        match=r"acquisition.form = 'lcb': not a parameter of "
        r"active.acquisition.DiscountedMaxUCB; allowed \['c', 'gamma'",
    ):
        acquisition_factory(
            {"_target_": "active.acquisition.DiscountedMaxUCB", "gamma": 1.0, "form": "lcb"}, ExperimentConfig()
        )


def test_an_acquisition_that_fails_numerically_executes_a_random_candidate_recorded():
    """A singular MDE posterior while scoring must not end a long run: the method warns, executes a random
    candidate (as random_plan would) and marks it ``plan_unscored`` for categories.csv."""
    from types import SimpleNamespace

    import numpy as np
    from linear_operator.utils.errors import NotPSDError

    from active.methods import ActiveChoice

    def failing(X):
        raise NotPSDError("not positive definite")

    cands = [SimpleNamespace(features=np.zeros((2, 3)), actions=np.full((2, 3), k)) for k in range(3)]
    with pytest.warns(RuntimeWarning, match="acquisition failed on 3 candidates.*plan_unscored"):
        ch = ActiveChoice({"c": 0.1}).choose(cands, np.random.default_rng(0), lambda: None, lambda kw: failing)
    assert ch.source == "plan_unscored" and ch.n_candidates == 3 and ch.scores is None
    assert (ch.actions == ch.chosen).all() and ch.chosen == int(np.random.default_rng(0).integers(3))


class KnownJoint(Model):
    """A joint latent posterior over indexed points (X[..., 0] is the index): mean, latent covariance and a constant
    observation noise fixed by hand, with the MDE view's ``mean_var`` and ``covariance``."""

    num_outputs = 1

    def __init__(self, mean, cov, noise):
        super().__init__()
        self.m = torch.tensor(mean, dtype=torch.float64)
        self.K = torch.tensor(cov, dtype=torch.float64)
        self.noise = noise

    def mean_var(self, X, observation_noise):
        i = X[..., 0].long()
        return self.m[i], self.K[i, i] + (self.noise if observation_noise else 0.0)

    def covariance(self, Xa, Xb):
        return self.K[Xa[:, 0].long()][:, Xb[:, 0].long()]

    def posterior(self, X, output_indices=None, observation_noise=False, posterior_transform=None):
        mean, var = self.mean_var(X, observation_noise)
        return GPyTorchPosterior(MultivariateNormal(mean, torch.diag_embed(var)))


def test_admission_gain_by_hand():
    """Reference: point 0 admitted now (mu + 2 sd = 0.0647 < 0.07), point 1 likely good but too uncertain (0.083),
    point 2 likely bad (0.123); candidates observe one point each (3: correlated with nothing)."""
    from math import erf, sqrt

    from active.acquisition import TrajectoryAdmissionGain

    K = [[4e-4, 0, 0, 0], [0, 9e-4, 0, 0], [0, 0, 9e-4, 0], [0, 0, 0, 9e-4]]
    model = KnownJoint([0.02, 0.02, 0.06, 0.0], K, noise=1e-4)
    ref = torch.tensor([[0.0], [1.0], [2.0]], dtype=torch.float64)
    acq = TrajectoryAdmissionGain(model, reference=ref, d_max=0.07, beta=2.0)
    cands = torch.tensor([[[1.0]], [[2.0]], [[3.0]]], dtype=torch.float64)  # 3 one-step trajectories

    def p_after(mu, latent):  # observing the point itself: v = latent^2 / (latent + noise)
        v = latent**2 / (latent + 1e-4)
        sd_after = sqrt(latent + 1e-4 - v)
        return 0.5 * (1 + erf((0.07 - 2 * sd_after - mu) / sqrt(v) / sqrt(2)))

    want = [p_after(0.02, 9e-4), p_after(0.06, 9e-4), 0.0]
    assert want[0] == pytest.approx(0.785, abs=1e-3) and want[1] == pytest.approx(0.268, abs=1e-3)
    assert acq(cands).tolist() == pytest.approx(want, abs=1e-8)  # (the 1e-9 relative jitter)
    assert int(acq(cands).argmax()) == 0  # the uncertain, probably good transition is worth observing
    # a two-step trajectory through both: gains add where the points are independent
    both = torch.tensor([[[1.0], [2.0]]], dtype=torch.float64)
    assert acq(both).item() == pytest.approx(want[0] + want[1], abs=1e-8)
    # observing a transition correlated with the admitted point 0 can only risk it: expected gain < 0 there
    K2 = [[4e-4, 3.6e-4], [3.6e-4, 4e-4]]
    risky = TrajectoryAdmissionGain(
        KnownJoint([0.02, 0.02], K2, noise=1e-4),
        reference=torch.tensor([[0.0]], dtype=torch.float64),
        d_max=0.07,
        beta=2.0,
    )
    v = 3.6e-4**2 / (4e-4 + 1e-4)  # v_0 = S_01^2 / (S_11 + noise)
    keep = 0.5 * (1 + erf((0.07 - 2 * sqrt(5e-4 - v) - 0.02) / sqrt(v) / sqrt(2)))  # P(still admitted) ~ 0.88
    gain = risky(torch.tensor([[[1.0]]], dtype=torch.float64)).item()
    assert gain == pytest.approx(keep - 1.0, abs=1e-8) and gain < 0


def test_admission_gain_refuses_a_model_without_covariance_and_a_bad_reference():
    from active.acquisition import TrajectoryAdmissionGain

    with pytest.raises(TypeError, match="covariance"):
        TrajectoryAdmissionGain(KnownPosterior())
    model = KnownJoint([0.0], [[1e-4]], noise=1e-4)
    with pytest.raises(ValueError, match="reference"):
        TrajectoryAdmissionGain(model, reference=torch.zeros(0, 1))
    with pytest.raises(ValueError, match="d_max"):
        TrajectoryAdmissionGain(model, d_max=0.0)


def test_admission_method_gets_the_test_beta_d_max_and_the_chunks_candidate_steps():
    """active_admission's acquisition is completed by the loop: beta = experiment.beta_test, d_max, and the
    reference = every step of every candidate of the chunk (active.loop._candidate_steps)."""
    from types import SimpleNamespace

    import numpy as np

    from active.acquisition import TrajectoryAdmissionGain
    from active.acquisition_factory import acquisition_factory
    from active.experiment import ExperimentConfig
    from active.loop import _candidate_steps
    from active.methods import build_method
    from active.run import compose_config

    cfg = compose_config(["experiment.methods=[active_admission]"])
    make = acquisition_factory(cfg["acquisition"], ExperimentConfig(d_max=0.05, beta_test=3.0))
    sets = [
        SimpleNamespace(candidates=[SimpleNamespace(features=np.full((2, 1), k + 2 * j)) for k in range(2)])
        for j in range(2)
    ] + [None]
    ref = _candidate_steps(sets)
    assert ref.shape == (8, 1) and sorted(set(ref[:, 0].tolist())) == [0.0, 1.0, 2.0, 3.0]
    assert _candidate_steps([None]) is None
    model = KnownJoint([0.0] * 4, torch.eye(4).mul(1e-4).tolist(), noise=1e-4)
    acq = make(model, build_method("active_admission", cfg["methods"]).acquisition, ref)
    assert type(acq) is TrajectoryAdmissionGain and acq.beta == 3.0 and acq.d_max == 0.05
    assert torch.equal(acq.reference, ref)
