"""Statistical behaviour of the MDE on synthetic data with input-dependent noise."""

from __future__ import annotations

import math

import pytest
import torch

from mde import GPMDE, calibration_report


def _data_1d(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Deviation-like 1-D data: smooth mean, noise std growing 10x across the domain."""
    g = torch.Generator().manual_seed(seed)
    X = torch.rand(n, 1, generator=g, dtype=torch.float64) * 4.0
    f = 1.0 + 0.5 * torch.sin(1.5 * X[:, 0])
    s = 0.05 + 0.2 * X[:, 0]
    y = f + s * torch.randn(n, generator=g, dtype=torch.float64)
    return X, y.clamp_min(0.0)


def _data_4d(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """4-D: mean depends on x0, x1; noise std on x2 (irrelevant to the mean), x3 is a distractor."""
    g = torch.Generator().manual_seed(seed)
    X = torch.rand(n, 4, generator=g, dtype=torch.float64)
    f = 0.6 + 0.3 * torch.sin(3.0 * X[:, 0]) + 0.2 * X[:, 1] ** 2
    s = 0.01 + 0.25 * X[:, 2] ** 2
    y = f + s * torch.randn(n, generator=g, dtype=torch.float64)
    return X, y.clamp_min(0.0)


CASES = {"1d": (_data_1d, 250), "4d": (_data_4d, 350)}
#: One torch thread: on a CPU shared with other busy processes, two OpenMP threads make the small
#: linear algebra here erratic (up to 10x slower); results are identical either way.
T1 = {"num_threads": 1}


@pytest.fixture(scope="module")
def fitted() -> dict:
    """Hetero- and homoscedastic fits per case (shared: fitting is the slow part)."""
    torch.manual_seed(0)
    out = {}
    for name, (make, n) in CASES.items():
        X, y = make(n, seed=1)
        Xt, yt = make(3000, seed=2)
        het = GPMDE(predict_dtype="float64", **T1).fit(X, y)
        hom = GPMDE(heteroscedastic=False, predict_dtype="float64", **T1).fit(X, y)
        out[name] = dict(X=X, y=y, Xt=Xt, yt=yt, het=het, hom=hom)
    return out


@pytest.mark.parametrize("case", list(CASES))
def test_heteroscedastic_is_calibrated_and_beats_homoscedastic(fitted, case):
    c = fitted[case]
    het = calibration_report(c["het"], c["Xt"], c["yt"])
    hom = calibration_report(c["hom"], c["Xt"], c["yt"])
    assert 0.90 <= het["coverage"]["0.95"] <= 0.99, het["coverage"]
    assert het["nll"] < hom["nll"] - 0.05, (het["nll"], hom["nll"])
    # the noise model must actually have learned the input dependence
    assert c["het"].noise_model is not None and c["hom"].noise_model is None
    assert len(c["het"].fit_info["log_ml_history"]) >= 1
    assert (
        c["het"].fit_info["log_ml_history"][c["het"].fit_info["selected_iteration"] - 1]
        > c["het"].fit_info["homoscedastic_log_ml"]
    )


def test_homoscedastic_noise_is_constant(fitted):
    c = fitted["1d"]
    noise = c["hom"].noise_std(torch.tensor([[0.3], [3.7]], dtype=torch.float64))
    assert noise[0] == noise[1] > 0
    expected = float(c["hom"].model.likelihood.noise) ** 0.5 * c["hom"].label_std
    assert float(noise[0]) == pytest.approx(expected, rel=1e-12)


def test_noise_grows_where_the_data_is_noisy(fitted):
    c = fitted["1d"]
    lo = c["het"].noise_std(torch.tensor([[0.3]], dtype=torch.float64))
    hi = c["het"].noise_std(torch.tensor([[3.7]], dtype=torch.float64))
    true_lo, true_hi = 0.05 + 0.2 * 0.3, 0.05 + 0.2 * 3.7
    assert float(hi / lo) > 3.0
    assert 0.5 * true_hi < float(hi) < 2.0 * true_hi
    assert 0.3 * true_lo < float(lo) < 3.0 * true_lo


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("kind", ["het", "hom"])
def test_prior_mean_fixed_at_zero_deviation(fitted, case, kind):
    c = fitted[case]
    mde = c[kind]
    y = c["y"]
    mu_z, sigma_z = float(y.mean()), float(y.std())
    assert mde.label_mean == pytest.approx(mu_z, rel=1e-12)
    assert mde.label_std == pytest.approx(sigma_z, rel=1e-12)
    mean_module = mde.model.mean_module
    assert not mean_module.raw_constant.requires_grad
    assert float(mean_module.constant) == pytest.approx(-mu_z / sigma_z, rel=1e-12)


@pytest.mark.parametrize("case", list(CASES))
def test_far_from_data_mean_returns_to_zero_and_std_grows(fitted, case):
    c = fitted[case]
    mde = c["het"]
    d = c["X"].shape[1]
    steps = torch.tensor([0.0, 2.0, 10.0, 1e3])
    Xq = c["X"].mean(dim=0) + steps.unsqueeze(1) * torch.ones(1, d) * 10.0  # walk away from the data
    mean, std = mde.predict(Xq)
    assert abs(float(mean[-1])) < 1e-6 * mde.label_std  # zero deviation, label units
    assert float(std[-1]) > 1.5 * float(mde.predict(c["X"])[1].median())
    assert torch.all(std[1:] > std[0])
    # the latent posterior reverts to the prior variance (outputscale, in label units)
    latent = mde.model.posterior(Xq[-1:].unsqueeze(1)).variance.reshape(())
    prior_var = float(mde.model.covar_module.outputscale) * mde.label_std**2
    assert float(latent) == pytest.approx(prior_var, rel=1e-9)


@pytest.mark.parametrize("kind", ["het", "hom"])
def test_predict_equals_botorch_posterior_with_noise(fitted, kind):
    c = fitted["4d"]
    mde = c[kind]
    Xq = c["Xt"][:200]
    mean, std = mde.predict(Xq)
    post = mde.model.posterior(Xq.unsqueeze(1), observation_noise=True)  # 200 x 1 x d
    torch.testing.assert_close(post.mean.reshape(-1), mean, rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(post.variance.reshape(-1).sqrt(), std, rtol=1e-7, atol=1e-9)
    latent = mde.model.posterior(Xq.unsqueeze(1)).variance.reshape(-1)
    assert torch.all(latent < std**2)  # latent-only posterior excludes the noise


def test_posterior_batch_q_shape_and_label_units(fitted):
    c = fitted["4d"]
    mde = c["het"]
    Xbq = c["Xt"][:24].reshape(4, 6, 4)  # b x q x d: e.g. 4 trajectories of 6 steps
    post = mde.model.posterior(Xbq)
    assert post.mean.shape == (4, 6, 1)
    assert post.distribution.covariance_matrix.shape == (4, 6, 6)
    torch.testing.assert_close(post.mean.reshape(-1), mde.predict(c["Xt"][:24])[0], rtol=1e-9, atol=1e-9)
    noisy = mde.model.posterior(Xbq, observation_noise=True)
    assert noisy.mean.shape == (4, 6, 1)
    assert torch.all(noisy.variance > post.variance)


def test_botorch_acquisition_functions_run_on_the_model(fitted):
    from botorch.acquisition import UpperConfidenceBound
    from botorch.acquisition.monte_carlo import qSimpleRegret
    from botorch.sampling import SobolQMCNormalSampler

    c = fitted["4d"]
    model = c["het"].model
    ucb = UpperConfidenceBound(model, beta=4.0)
    vals = ucb(c["Xt"][:10].unsqueeze(1))
    mean, _ = c["het"].predict(c["Xt"][:10])
    latent_std = model.posterior(c["Xt"][:10].unsqueeze(1)).variance.reshape(-1).sqrt()
    torch.testing.assert_close(vals, mean + 2.0 * latent_std, rtol=1e-8, atol=1e-10)
    qsr = qSimpleRegret(model, sampler=SobolQMCNormalSampler(sample_shape=torch.Size([64]), seed=0))
    out = qsr(c["Xt"][:30].reshape(5, 6, 4))
    assert out.shape == (5,) and torch.isfinite(out).all()


def test_float32_fast_path_close_to_float64(fitted):
    c = fitted["4d"]
    mde64 = c["het"]
    mde32 = GPMDE(predict_dtype="float32")
    keys = ("X", "y", "bounds", "mean_model", "train_Yvar", "noise_model", "noise_train", "info")
    mde32._fitted = mde32._make_fitted(*(getattr(mde64._fitted, k) for k in keys))
    mde32._n_features = mde64.n_features
    m64, s64 = mde64.predict(c["Xt"])
    m32, s32 = mde32.predict(c["Xt"])
    assert float((m32 - m64).abs().max()) < 5e-3 * mde64.label_std
    assert float(((s32 - s64).abs() / s64).max()) < 5e-3


def test_predict_is_batched_chunked_and_gradient_free(fitted):
    c = fitted["1d"]
    mde = GPMDE(predict_dtype="float64", predict_chunk=7)
    mde._fitted, mde._n_features = c["het"]._fitted, 1
    Xq = c["Xt"][:50].clone().requires_grad_(True)
    mean, std = mde.predict(Xq)
    ref_mean, ref_std = c["het"].predict(c["Xt"][:50])
    assert not mean.requires_grad and not std.requires_grad
    torch.testing.assert_close(mean, ref_mean, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(std, ref_std, rtol=1e-12, atol=1e-12)
    assert mean.dtype == torch.float64 and mde.predict(c["Xt"][:3].float())[0].dtype == torch.float32


@pytest.mark.parametrize("nu", [0.5, 1.5])
@pytest.mark.parametrize("scaling", ["none", "normalize"])
def test_other_kernels_and_input_scaling(nu, scaling):
    torch.manual_seed(0)
    X, y = _data_4d(80, seed=3)
    X = X * torch.tensor([1.0, 10.0, 0.1, 100.0]) + 5.0  # unscaled, offset features
    mde = GPMDE(nu=nu, input_scaling=scaling, max_iters=2, predict_dtype="float64", **T1).fit(X, y)
    Xq = X[:20] + 0.01
    mean, std = mde.predict(Xq)
    post = mde.model.posterior(Xq.unsqueeze(1), observation_noise=True)
    torch.testing.assert_close(post.mean.reshape(-1), mean, rtol=1e-8, atol=1e-8)
    torch.testing.assert_close(post.variance.reshape(-1).sqrt(), std, rtol=1e-6, atol=1e-8)
    assert mde.model.covar_module.base_kernel.nu == nu


def test_hyperparameter_subset_then_condition_on_all():
    torch.manual_seed(0)
    X, y = _data_1d(120, seed=4)
    mde = GPMDE(max_fit_points=50, max_iters=2, predict_dtype="float64", **T1).fit(X, y)
    assert mde.fit_info["n_fit_points"] == 50 and mde.n_train == 120
    assert mde.model.train_targets.shape == (120,)
    mean, std = mde.predict(X[:10])
    post = mde.model.posterior(X[:10].unsqueeze(1), observation_noise=True)
    torch.testing.assert_close(post.mean.reshape(-1), mean, rtol=1e-8, atol=1e-8)
    torch.testing.assert_close(post.variance.reshape(-1).sqrt(), std, rtol=1e-6, atol=1e-8)


def test_prior_before_fit_and_after_empty_fit():
    mde = GPMDE()
    mean, std = mde.predict(torch.rand(5, 3))
    assert torch.equal(mean, torch.zeros(5)) and torch.equal(std, torch.full((5,), 1.0))
    post = mde.model.posterior(torch.rand(2, 4, 3))
    assert post.mean.shape == (2, 4, 1) and torch.allclose(post.variance, torch.ones(2, 4, 1))
    mde = GPMDE(prior_std=0.25).fit(torch.empty(0, 3), torch.empty(0))
    assert not mde.is_fitted and mde.n_features == 3
    assert torch.allclose(mde.predict(torch.rand(2, 3))[1], torch.full((2,), 0.25))
    with pytest.raises(ValueError, match="d=2"):
        mde.predict(torch.rand(2, 2))


def test_mll_closure_matches_gpytorch():
    """The fast closed-form loss is exactly GPyTorch's exact marginal likelihood (value and grads)."""
    from gpytorch.mlls import ExactMarginalLogLikelihood

    from mde.gp import build_mean_gp, data_bounds, exact_nll

    torch.manual_seed(0)
    X, y = _data_4d(60, seed=5)
    X[7] = X[8]  # duplicate input
    for nu, priors in ((0.5, "none"), (1.5, "none"), (2.5, "none"), (2.5, "gamma"), (2.5, "lognormal")):
        for Yvar in (None, 0.001 + 0.01 * torch.rand(60, dtype=torch.float64)):
            m = build_mean_gp(X, y, nu=nu, bounds=data_bounds(X), noise_floor=1e-4, train_Yvar=Yvar, priors=priors)
            assert (
                len(list(m.named_priors()))
                == {"none": 0, "gamma": 3 if Yvar is None else 2, "lognormal": 2 if Yvar is None else 1}[priors]
            )
            m.covar_module.base_kernel.lengthscale = torch.tensor([[0.3, 0.5, 2.0, 0.7]])
            m.mean_module.raw_constant.requires_grad_(True)
            m.train()
            mll = ExactMarginalLogLikelihood(m.likelihood, m)
            ref = -mll(m(*m.train_inputs), m.train_targets, m.transform_inputs(m.train_inputs[0]))
            ref_grads = torch.autograd.grad(ref, [p for p in m.parameters() if p.requires_grad])
            mine = exact_nll(m)
            grads = torch.autograd.grad(mine, [p for p in m.parameters() if p.requires_grad])
            assert float(mine.detach()) == pytest.approx(float(ref.detach()), rel=1e-8)
            for a, b in zip(grads, ref_grads):
                torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-9)


def test_log_chi2_bias_constant():
    """exp(1.27) r^2 corrects E[log r^2] = log sigma^2 - 1.27 for a Gaussian residual."""
    from mde.model import LOG_CHI2_BIAS

    digamma_half = torch.digamma(torch.tensor(0.5, dtype=torch.float64)).item()
    assert LOG_CHI2_BIAS == pytest.approx(-(digamma_half + math.log(2.0)), rel=1e-12)


def test_lengthscales_stay_under_their_bound():
    """lengthscale_max: every lengthscale of the mean and the noise GP at most that many stds of its input,
    where the unbounded fit's noise GP goes far beyond (a feature the noise does not depend on)."""
    torch.manual_seed(0)
    X, y = _data_4d(120, seed=5)
    X = X * torch.tensor([1.0, 10.0, 0.1, 100.0])  # unscaled features
    std = X.std(dim=0)
    free = GPMDE(max_iters=2, **T1).fit(X, y)
    capped = GPMDE(max_iters=2, lengthscale_max=2.0, **T1).fit(X, y)
    ls = lambda gp: gp.covar_module.base_kernel.lengthscale.detach().reshape(-1)  # noqa: E731
    assert (ls(free.noise_model) / std).max() > 2.0
    for gp in (capped.model, capped.noise_model):
        assert ((ls(gp) / std) <= 2.0 * (1 + 1e-9)).all()
    mean, std_pred = capped.predict(X[:10])
    post = capped.model.posterior(X[:10].unsqueeze(1), observation_noise=True)
    torch.testing.assert_close(post.variance.reshape(-1).sqrt(), std_pred, rtol=1e-6, atol=1e-8)
    with pytest.raises(ValueError, match=r"lengthscale_max must be a finite number > 0, got -1"):
        GPMDE(lengthscale_max=-1.0)


def test_noise_lengthscale_max_bounds_the_noise_gp_alone():
    """noise_lengthscale_max: the noise GP's lengthscales under that bound, the mean GP's built as without it
    (unbounded here); saved and loaded with the model."""
    X, y = _data_4d(120, seed=5)
    X = X * torch.tensor([1.0, 10.0, 0.1, 100.0])
    std = X.std(dim=0)
    ls = lambda gp: gp.covar_module.base_kernel.lengthscale.detach().reshape(-1)  # noqa: E731
    m = GPMDE(max_iters=2, noise_lengthscale_max=2.0, **T1).fit(X, y)
    assert ((ls(m.noise_model) / std) <= 2.0 * (1 + 1e-6)).all()  # the Interval transform's rounding
    assert (ls(m.model) / std).max() > 2.0  # the mean GP is not bounded
    assert GPMDE(lengthscale_max=3.0).config.noise_lengthscale_bound == 3.0
    assert GPMDE(lengthscale_max=3.0, noise_lengthscale_max=1.0).config.noise_lengthscale_bound == 1.0
    with pytest.raises(ValueError, match=r"noise_lengthscale_max must be a finite number > 0, got 0"):
        GPMDE(noise_lengthscale_max=0)


def test_latent_std_min_keeps_unvisited_inputs_unknown():
    """latent_std_min: a GP that has seen only small deviations (z-scored labels of std 0.003) is narrow
    far from its data without the bound, so ``mu + 2 sigma < d_max`` would admit inputs it never saw;
    with the bound its latent std there is the bound (label units), near the data it hardly moves."""
    g = torch.Generator().manual_seed(0)
    X = torch.rand(40, 3, generator=g, dtype=torch.float64)
    y = 0.02 + 0.01 * torch.rand(40, generator=g, dtype=torch.float64)  # benign labels only
    far = torch.tensor([[1e8, -1e8, 1e8]], dtype=torch.float64)  # beyond any lengthscale (<= ~1e5, RAW_UPPER)
    latent_std = lambda m, Xq: m.model.posterior(Xq.unsqueeze(1)).variance.reshape(-1).sqrt()  # noqa: E731
    free = GPMDE(hyperparameter_priors="none", **T1).fit(X, y)
    floored = GPMDE(latent_std_min=0.05, hyperparameter_priors="none", **T1).fit(X, y)
    assert float(latent_std(free, far)) < 0.035  # mu + 2 sigma < d_max = 0.07 where there is no data
    assert float(latent_std(floored, far)) == pytest.approx(0.05, rel=1e-6)
    mean, std = floored.predict(far)
    assert float(mean + 2 * std) > 0.07
    near_free, near_floored = free.predict(X[:5]), floored.predict(X[:5])
    torch.testing.assert_close(near_floored[0], near_free[0], rtol=0, atol=2e-3)
    # labels of a wide spread: the bound is far below the fitted outputscale and does not bind (the
    # optimiser's path through the bound's transform differs, so equal to the optimiser's tolerance)
    wide = y * 100.0
    a = GPMDE(hyperparameter_priors="none", **T1).fit(X, wide).predict(far)
    b = GPMDE(latent_std_min=0.05, hyperparameter_priors="none", **T1).fit(X, wide).predict(far)
    torch.testing.assert_close(a, b, rtol=1e-3, atol=1e-9)
    with pytest.raises(ValueError, match=r"latent_std_min must be a finite number > 0, got 0"):
        GPMDE(latent_std_min=0)


def test_latent_std_max_bounds_the_latent_std_far_from_the_data():
    """latent_std_max: the latent std far from the data is at most the bound (label units), with or
    without latent_std_min below it; bounds in the wrong order are refused before any fit."""
    g = torch.Generator().manual_seed(0)
    X = torch.rand(40, 3, generator=g, dtype=torch.float64)
    y = 0.3 * torch.rand(40, generator=g, dtype=torch.float64)  # a wide spread: the free fit is far above 0.02
    far = torch.tensor([[1e8, -1e8, 1e8]], dtype=torch.float64)
    latent_std = lambda m: float(m.model.posterior(far.unsqueeze(1)).variance.reshape(-1).sqrt())  # noqa: E731
    assert latent_std(GPMDE(**T1).fit(X, y)) > 0.05
    assert latent_std(GPMDE(latent_std_max=0.02, **T1).fit(X, y)) <= 0.02 * (1 + 1e-6)
    both = GPMDE(latent_std_min=0.01, latent_std_max=0.02, **T1).fit(X, y)
    assert 0.01 * (1 - 1e-6) <= latent_std(both) <= 0.02 * (1 + 1e-6)
    with pytest.raises(ValueError, match=r"latent_std_min \(0.05\) must be below latent_std_max \(0.02\)"):
        GPMDE(latent_std_min=0.05, latent_std_max=0.02)
    with pytest.raises(ValueError, match=r"latent_std_max must be a finite number > 0, got -1"):
        GPMDE(latent_std_max=-1)


def test_label_max_fits_large_deviations_as_that_value():
    """label_max: labels above it are fitted as it (what train_y reports); a fit without labels above it
    is unchanged; a large deviation stays far above d_max in the prediction."""
    g = torch.Generator().manual_seed(1)
    X = torch.rand(40, 3, generator=g, dtype=torch.float64)
    y = 0.02 + 0.01 * torch.rand(40, generator=g, dtype=torch.float64)
    y_spill = y.clone()
    y_spill[X[:, 0] > 0.8] = 1.8  # whole spills in one corner
    capped = GPMDE(label_max=0.3, **T1).fit(X, y_spill)
    assert float(capped.train_y.max()) == 0.3 and float(capped.train_y.min()) == float(y.min())
    ref = GPMDE(**T1).fit(X, y_spill.clamp(max=0.3))
    torch.testing.assert_close(capped.predict(X), ref.predict(X))
    corner = X[X[:, 0] > 0.8]
    mean, std = capped.predict(corner)
    assert (mean > 0.2).all()
    same = GPMDE(label_max=0.3, **T1).fit(X, y).predict(X)
    torch.testing.assert_close(same, GPMDE(**T1).fit(X, y).predict(X))
    with pytest.raises(ValueError, match=r"label_max must be a finite number > 0, got -1"):
        GPMDE(label_max=-1)


def test_gamma_priors_keep_lengthscales_in_range_and_survive_saving(tmp_path):
    """hyperparameter_priors="gamma": the MAP fit keeps every lengthscale within the Gamma(3, 6) prior's
    range (a few units) where the maximum-likelihood noise GP goes far beyond on an irrelevant feature;
    the priors come back with a saved model (same predictions; "lognormal" too); a bad value names the field."""
    X, y = _data_4d(120, seed=5)
    ls = lambda gp: gp.covar_module.base_kernel.lengthscale.detach().reshape(-1)  # noqa: E731
    free = GPMDE(max_iters=2, hyperparameter_priors="none", **T1).fit(X, y)
    gamma = GPMDE(max_iters=2, hyperparameter_priors="gamma", **T1).fit(X, y)
    assert ls(free.noise_model).max() > 5.0
    for gp in (gamma.model, gamma.noise_model):
        assert ls(gp).max() < 3.0 and len(list(gp.named_priors())) >= 2
    assert torch.isfinite(gamma.predict(X)[1]).all()
    path = tmp_path / "mde.pt"
    gamma.save(path)
    torch.testing.assert_close(GPMDE.load(path).predict(X[:20]), gamma.predict(X[:20]))
    lognormal = GPMDE(max_iters=2, hyperparameter_priors="lognormal", **T1).fit(X, y)
    lognormal.save(path)
    torch.testing.assert_close(GPMDE.load(path).predict(X[:20]), lognormal.predict(X[:20]))
    with pytest.raises(
        ValueError,
        match=r"hyperparameter_priors must be one of \('none', 'gamma', 'lognormal'\), "
        r"got 'cauchy'",
    ):
        GPMDE(hyperparameter_priors="cauchy")
