"""Regressions found on simulator data."""

import warnings
from pathlib import Path

import pytest
import torch

from mde import GPMDE

DATA = Path(__file__).parent / "data" / "mde_abnormal_line_search.pt"


def test_fit_survives_abnormal_line_search_stops():
    """On these 60 transitions L-BFGS-B stops with an "ABNORMAL" line search; the iterate it returns is a
    usable fit, not a failed one that would leave the MDE at its prior."""
    d = torch.load(DATA)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mde = GPMDE(num_threads=1).fit(d["X"], d["y"])
    assert mde.is_fitted
    assert not [w for w in caught if "keeping the" in str(w.message)]
    mean, std = mde.predict(d["X"])
    assert torch.isfinite(mean).all() and (std > 0).all()
    assert (mean - d["y"]).abs().median() < 0.05  # it learned the data, not the prior (mean 0, std 1)


def _explicit_gp(model, Xq):
    """A fitted SingleTaskGP's kernel from explicit float64 differences (no |a|^2 + |b|^2 - 2ab expansion), the
    reference when lengthscales span 1e-11 to 1e4: (k, K with the training noise, transformed train and query
    inputs)."""
    from mde.gp import matern_from_dist, train_inputs_transformed

    ls = model.covar_module.base_kernel.lengthscale.detach().reshape(-1)
    os_ = model.covar_module.outputscale.detach()
    Xt = train_inputs_transformed(model).double()
    tf = getattr(model, "input_transform", None)
    Xqt = Xq if tf is None else tf(Xq)
    k = lambda A, B: matern_from_dist(((A[:, None] - B[None]) / ls).pow(2).sum(-1).sqrt(), 2.5) * os_  # noqa: E731
    K = k(Xt, Xt) + torch.diag(model.likelihood.noise.detach().reshape(-1).expand(len(Xt)))
    return k, K, Xt, Xqt


def _explicit_gp_mean(model, Xq):
    """The posterior mean (label units) from :func:`_explicit_gp`."""
    k, K, Xt, Xqt = _explicit_gp(model, Xq)
    c = model.mean_module.constant.detach()
    z = k(Xqt, Xt) @ torch.linalg.solve(K, model.train_targets.double() - c) + c
    otf = model.outcome_transform
    return z * otf.stdvs.reshape(()) + otf.means.reshape(())


def _explicit_gp_latent_var(model, Xq):
    """The latent posterior variance (label units) from :func:`_explicit_gp`."""
    k, K, Xt, Xqt = _explicit_gp(model, Xq)
    kq = k(Xqt, Xt)
    var_z = k(Xqt[:1], Xqt[:1]).reshape(()) - (kq * torch.linalg.solve(K, kq.T).T).sum(-1)
    return var_z * model.outcome_transform.stdvs.reshape(()) ** 2


def test_predict_matches_an_explicit_posterior_on_simulator_features():
    """With the float32 fast path, these transitions give a noise GP mean of +0.49 (log variance)
    where the GP interpolates -1.28 at a training point, and lose the latent variance entirely, so
    ``predict`` (the planner's precondition) and the acquisitions disagree by up to 0.68 in variance:
    hence the float64 default.

    The fit here puts lengthscales of 1e-11 to 1e-8 on 0/1 features (which ones, and how small, depends on
    the CPU's floating point: AVX-512 machines land on 1e-11); GPyTorch's own distance then loses the
    other features to cancellation (noise GP mean -6.55 at query 0 on some CPUs; on AVX-512 a
    latent variance of 1e-5 where the explicit computation gives 9e-4). So ``predict`` and the BoTorch view the
    acquisitions read (``marginal_model``) are checked against explicit float64 differences, not against
    GPyTorch's posterior, and the noise cache against the same reference."""
    d = torch.load(Path(__file__).parent / "data" / "mde_noise_extrapolation.pt")
    # maximum likelihood: the degenerate lengthscales this test is about (hyperparameter priors keep them off)
    mde = GPMDE(num_threads=1, hyperparameter_priors="none").fit(d["X"], d["y"])
    _, std = mde.predict(d["X_query"])
    f = mde._fitted
    Xq = d["X_query"].double()
    noise = f.mean_model.noise_variance(Xq) * f.mean_model.outcome_transform.stdvs.reshape(()) ** 2
    reference = _explicit_gp_latent_var(f.mean_model, Xq) + noise
    torch.testing.assert_close(std.double() ** 2, reference, rtol=0.02, atol=1e-6)
    view = mde.marginal_model.posterior(d["X_query"].unsqueeze(-2), observation_noise=True)
    torch.testing.assert_close(view.variance.reshape(-1).double(), std.double() ** 2, rtol=1e-6, atol=1e-9)
    m, s = f.noise_affine
    at_train = f.noise_cache.mean(f.noise_train[0][:3].double()) * s + m
    torch.testing.assert_close(at_train, f.noise_train[1][:3].double(), rtol=0, atol=0.01)
    torch.testing.assert_close(f.noise_cache.mean(Xq) * s + m, _explicit_gp_mean(f.noise_model, Xq), rtol=0, atol=0.02)


def test_noise_never_exceeds_the_largest_training_noise():
    d = torch.load(Path(__file__).parent / "data" / "mde_noise_extrapolation.pt")
    mde = GPMDE(num_threads=1).fit(d["X"], d["y"])
    far = d["X"] + torch.linspace(-3.0, 3.0, d["X"].shape[1])
    cap = float(mde._fitted.noise_train[1].max().exp().sqrt())
    assert (mde.noise_std(far) <= cap * (1 + 1e-6)).all()
    assert (mde.model.noise_variance(far.double()) * mde.label_std**2 <= cap**2 * (1 + 1e-6)).all()


def test_fit_with_a_vanishing_lengthscale_on_a_barely_varying_feature():
    """The move GP of a quick run's first round (seed 3): 14 transitions whose volume fractions are 1.000 / 0.000
    but for two rows (0.974 / 0.026). The fit puts lengthscales of ~1e-10 on those two features, where the
    matmul form of the distance (|z|^2 + |z'|^2 - 2 z.z') loses the other features to cancellation: rows equal in
    the fractions got distances of order 1, the kernel matrix was not positive definite at the optimum, the fit
    failed and the MDE kept its prior (std 1 everywhere). Distances from explicit differences
    (``mde.gp.scaled_dist``, used by the fit, the prediction cache's training kernel and its ``cross0``) fix it, and
    the cached prediction equals an explicit-difference reference."""
    from mde.gp import scaled_dist

    d = torch.load(Path(__file__).parent / "data" / "mde_tiny_lengthscale_fit.pt")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mde = GPMDE(num_threads=1, hyperparameter_priors="none").fit(d["X"], d["y"])  # maximum likelihood
    assert mde.is_fitted and not [w for w in caught if "keeping the" in str(w.message)]
    assert mde.model.covar_module.base_kernel.lengthscale.min() < 1e-6  # the regime this test is about
    mean, std = mde.predict(d["X"])
    assert (std < 0.1).all()  # not the prior
    torch.testing.assert_close(mean.double(), _explicit_gp_mean(mde.model, d["X"]), rtol=0, atol=1e-6)
    big = d["y"] > 0.05  # the two moves that went wrong (a matmul-form cache gave 0.112 where the label is 0.292)
    torch.testing.assert_close(mean.double()[big], d["y"][big], rtol=0, atol=0.01)
    Z = torch.tensor([[1e8, 0.3], [1e8, 0.3], [1e8 + 1.0, 0.3]], dtype=torch.float64)
    assert scaled_dist(Z).tolist() == [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 1.0, 0.0]]


def test_grouped_acquisition_reads_the_fits_own_factorisation():
    """40 pours of a quick run (goals 0.3-0.6, active_balanced seed 1, iteration 3): the fit needs a Cholesky
    jitter of 4.5e-3 (accepted by the MDE's own cap), while GPyTorch's posterior refactorises the kernel with
    a cap of 1e-3 and raised NotPSDError while the acquisition scored candidates; the whole run died. The
    acquisition's BoTorch view now reads the fit's cached factorisation (the planner's numbers)."""
    from active.acquisition import DiscountedMaxUCB
    from mde import GroupedMDE

    d = torch.load(Path(__file__).parent / "data" / "mde_gpytorch_cholesky_cap.pt")
    X = d["X"]  # column 5 is the skill: every row a move (group 0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mde = GroupedMDE(group_column=5, num_threads=1).fit(X, d["y"])
    assert mde.groups[0.0].is_fitted
    trajectories = X[:36].reshape(4, 9, X.shape[1])
    post = mde.model.posterior(trajectories, observation_noise=True)
    mean, std = mde.predict(X[:36])
    torch.testing.assert_close(post.mean.reshape(-1), mean, rtol=0, atol=1e-12)
    torch.testing.assert_close(post.variance.reshape(-1).sqrt(), std, rtol=1e-12, atol=1e-12)
    latent = mde.model.posterior(trajectories).variance.reshape(-1)
    assert (latent < std**2).all()  # without observation noise: the latent variance alone
    scores = DiscountedMaxUCB(mde.model, c=0.1)(trajectories)
    assert scores.shape == (4,) and torch.isfinite(scores).all()


def test_the_ungrouped_mde_gives_acquisitions_the_same_factorisation():
    """The same 40 pours on one GP (the ablation ``mde._target_=mde.GPMDE``): the acquisitions'
    view (``marginal_model``, what ``active.loop.acquisition_factory`` hands them) reads the fit's cache."""
    from active.acquisition import DiscountedMaxUCB

    d = torch.load(Path(__file__).parent / "data" / "mde_gpytorch_cholesky_cap.pt")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mde = GPMDE(num_threads=1).fit(d["X"], d["y"])
    trajectories = d["X"][:36].reshape(4, 9, -1)
    post = mde.marginal_model.posterior(trajectories, observation_noise=True)
    mean, std = mde.predict(d["X"][:36])
    torch.testing.assert_close(post.mean.reshape(-1), mean, rtol=0, atol=1e-12)
    torch.testing.assert_close(post.variance.reshape(-1).sqrt(), std, rtol=1e-12, atol=1e-12)
    extra = mde.marginal_model.posterior(trajectories, observation_noise=torch.full((4, 9, 1), 0.01))
    latent = mde.marginal_model.posterior(trajectories).variance
    torch.testing.assert_close(extra.variance, latent + 0.01)
    assert torch.isfinite(DiscountedMaxUCB(mde.marginal_model, c=0.1)(trajectories)).all()


@pytest.mark.parametrize("case", ["noise_floor", "lengthscale_zero"])
def test_lognormal_priors_keep_small_data_fits_off_the_degenerate_optima(case):
    """Two move GPs of the paper protocol's first round (active_admission, seeds 3 and 1; the default
    MDE, homoscedastic on labels capped at 0.1). Maximum likelihood puts the first's noise on the floor (1e-4 of
    the label variance: the GP interpolates 24 moves, and far from them the std is the outputscale's) and one
    lengthscale of the second at ~1e-7 of its input's range (a bad move explained by an odd volume fraction):
    rounds whose test planner then found plans for 0.10 of the problems. BoTorch's current default priors
    (``hyperparameter_priors="lognormal"``) keep both off those optima."""
    d = torch.load(Path(__file__).parent / "data" / "mde_small_data_degenerate.pt")[case]
    cfg = dict(heteroscedastic=False, label_max=0.1, num_threads=1)

    def fitted(priors: str) -> tuple[float, float]:
        gp = GPMDE(cfg, hyperparameter_priors=priors).fit(d["X"], d["y"])._fitted.mean_model
        Xt = gp.train_inputs[0]
        span = Xt.max(0).values - Xt.min(0).values
        rel = (gp.covar_module.base_kernel.lengthscale.detach().ravel() / span.clamp_min(1e-12))[span > 0]
        return float(gp.likelihood.noise), float(rel.min())

    noise, rel_ls = fitted("none")
    assert (noise < 2e-4) if case == "noise_floor" else (rel_ls < 1e-4)  # the degenerate fit this test is about
    noise, rel_ls = fitted("lognormal")
    assert noise > 1e-3 and rel_ls > 0.05
