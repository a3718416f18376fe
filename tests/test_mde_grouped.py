"""GroupedMDE: one heteroscedastic GP per value of a categorical feature (the action's skill)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import mde
from mde import GPMDE, GroupedMDE
from planner import features

T1 = {"num_threads": 1, "fit_maxiter": 60}


def _two_skills(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Column 2 is a skill code 0/1; the deviation depends on x0 for skill 0 and on x1 for skill 1,
    with a different scale, so one stationary kernel over both is a poor prior."""
    g = torch.Generator().manual_seed(seed)
    X = torch.rand(n, 4, generator=g, dtype=torch.float64)
    X[:, 2] = (X[:, 2] > 0.5).double()
    f = torch.where(X[:, 2] > 0, 0.2 * torch.sin(6.0 * X[:, 1]) ** 2, 0.05 * X[:, 0])
    y = (f + 0.005 * torch.randn(n, generator=g, dtype=torch.float64)).clamp_min(0.0)
    return X, y


@pytest.fixture(scope="module")
def grouped() -> tuple[GroupedMDE, torch.Tensor, torch.Tensor]:
    X, y = _two_skills(160, 0)
    return GroupedMDE(group_column=2, **T1).fit(X, y), X, y


def test_each_group_is_its_own_gp(grouped) -> None:
    m, X, y = grouped
    assert sorted(m.groups) == [0.0, 1.0] and m.n_train == len(y)
    rows = X[:, 2] == 1
    alone = GPMDE(**T1).fit(X[rows], y[rows])
    for a, b in zip(alone.predict(X[rows]), m.predict(X[rows])):
        assert torch.equal(a, b)


def test_generalises_better_than_one_gp_across_groups() -> None:
    X, y = _two_skills(160, 0)
    Xt, yt = _two_skills(400, 1)
    err_grouped = (GroupedMDE(group_column=2, **T1).fit(X, y).predict(Xt)[0] - yt).abs().mean()
    err_one = (GPMDE(**T1).fit(X, y).predict(Xt)[0] - yt).abs().mean()
    assert err_grouped < err_one


def test_unseen_group_predicts_the_prior(grouped) -> None:
    m, X, _ = grouped
    q = X[:3].clone()
    q[:, 2] = 7.0
    mean, std = m.predict(q)
    assert torch.all(mean == 0) and torch.allclose(std, torch.full((3,), m.config.prior_std, dtype=std.dtype))


def _matern52(A: torch.Tensor, B: torch.Tensor, lengthscale: torch.Tensor) -> torch.Tensor:
    a = math.sqrt(5.0) * torch.cdist(A / lengthscale, B / lengthscale)
    return (1.0 + a + a * a / 3.0) * torch.exp(-a)


def _closed_form(gp, X: torch.Tensor, y: torch.Tensor, noise: torch.Tensor, Xq: torch.Tensor):
    """Posterior mean and latent variance at ``Xq`` (units of ``y``) of a constant-mean ARD Matern-5/2 GP with the
    fitted hyperparameters of ``gp`` (outputscale, lengthscales, constant, in z-scored units), conditioned on
    (X, y) z-scored as BoTorch's Standardize does, with per-row noise ``noise`` (z-scored units): plain torch."""
    k = gp.covar_module
    s2, ls, c = float(k.outputscale), k.base_kernel.lengthscale.detach().reshape(-1), float(gp.mean_module.constant)
    mu, sd = y.mean(), y.std()
    L = torch.linalg.cholesky(s2 * _matern52(X, X, ls) + torch.diag(noise.expand(len(y))))
    Kq = s2 * _matern52(Xq, X, ls)
    alpha = torch.cholesky_solve(((y - mu) / sd - c).unsqueeze(-1), L).squeeze(-1)
    V = torch.linalg.solve_triangular(L, Kq.T, upper=False)
    return (c + Kq @ alpha) * sd + mu, (s2 - (V * V).sum(0)) * sd**2


def test_each_groups_posterior_is_the_closed_form_gp_on_its_own_rows(grouped) -> None:
    """The BoTorch posterior of a GroupedMDE, for queries of both groups in one batch, against each group's GP
    written out in plain torch from its fitted hyperparameters and that group's rows of the training data only:
    the latent mean and variance, and the predictive variance with the heteroscedastic noise, whose log the
    noise GP's closed-form mean gives (capped at its largest training value, floored as the MDE floors it).

    Measured here: relative differences up to 3e-11 (latent variance) and 2e-12 (predictive std), absolute up to
    3e-14 in the mean (labels up to 0.2); a GP fitted on the wrong rows, or one that mixes the groups, is off by
    orders of magnitude more."""
    m, X, y = grouped
    g = torch.Generator().manual_seed(5)
    Xq = torch.cat([X[:6], torch.rand(6, 4, generator=g, dtype=torch.float64)])  # training rows and new ones
    Xq[6:, 2] = torch.tensor([0.0, 1.0, 0.0, 1.0, 1.0, 0.0], dtype=torch.float64)
    latent = m.model.posterior(Xq.reshape(3, 4, 4))
    noisy = m.model.posterior(Xq.reshape(3, 4, 4), observation_noise=True)
    assert latent.mean.shape == noisy.mean.shape == (3, 4, 1)
    latent_mean, latent_var = latent.mean.reshape(-1), latent.variance.reshape(-1)
    predictive_var = noisy.variance.reshape(-1)
    for value in (0.0, 1.0):
        own, q = X[:, 2] == value, Xq[:, 2] == value
        assert 2 <= q.sum() <= 10
        gp = m.groups[value].model  # the group's fitted GP: its hyperparameters, its noise GP
        mean, var = _closed_form(gp, X[own], y[own], gp.likelihood.noise.detach().reshape(-1), Xq[q])
        nm = gp.noise_model
        log_noise = nm.train_targets * float(nm.outcome_transform.stdvs) + float(nm.outcome_transform.means)
        log_noise_q, _ = _closed_form(nm, X[own], log_noise, nm.likelihood.noise.detach().reshape(-1), Xq[q])
        noise = (log_noise_q.clamp_max(log_noise.max()).exp() / y[own].var()).clamp_min(m.config.noise_floor)
        torch.testing.assert_close(latent_mean[q], mean, rtol=0.0, atol=1e-12)
        torch.testing.assert_close(latent_var[q], var, rtol=1e-9, atol=0.0)
        torch.testing.assert_close(predictive_var[q], var + noise * y[own].var(), rtol=1e-9, atol=0.0)
        torch.testing.assert_close(m.predict(Xq[q])[1] ** 2, predictive_var[q], rtol=1e-12, atol=0.0)


def test_save_load_and_pickle_round_trip(grouped, tmp_path) -> None:
    import pickle

    m, X, _ = grouped
    back = mde.load(m.save(tmp_path / "m.pt"))
    assert isinstance(back, GroupedMDE) and torch.equal(back.train_X, m.train_X)
    assert torch.equal(back.predict(X)[1], m.predict(X)[1])
    assert torch.equal(pickle.loads(pickle.dumps(m)).predict(X)[0], m.predict(X)[0])
    assert isinstance(mde.load(GPMDE(**T1).save(tmp_path / "h.pt")), GPMDE)


def test_without_group_column_it_is_one_gp() -> None:
    X, y = _two_skills(80, 2)
    a, b = GroupedMDE(**T1).fit(X, y), GPMDE(**T1).fit(X, y)
    assert torch.equal(a.predict(X)[1], b.predict(X)[1])


def test_bad_group_column_is_refused() -> None:
    with pytest.raises(ValueError, match="group_column"):
        GroupedMDE(group_column=-1)
    with pytest.raises(ValueError, match="group_column=9"):
        GroupedMDE(group_column=9).fit(torch.rand(5, 3, dtype=torch.float64), torch.rand(5, dtype=torch.float64))
    with pytest.raises(ValueError, match="GroupedMDE"):
        GPMDE(group_column=1)


def test_default_config_groups_by_the_skill() -> None:
    """configs/mde/default.yaml's group_column must be the column where features() puts the skill."""
    from mde import MDEConfig

    cfg = MDEConfig.from_yaml("configs/mde/default.yaml")
    s, a = np.zeros((2, 5)), np.array([[0.0, 0.3, 0.2], [1.0, 1.4, 0.5]])
    assert cfg.group_column is not None and np.array_equal(features(s, a)[:, cfg.group_column], a[:, 0])


def test_cross_validation_holds_out_whole_groups() -> None:
    from mde.calibration import cross_validate

    X, y = _two_skills(60, 3)
    traj = torch.arange(60) // 3  # 20 "trajectories" of 3 steps
    mean, std = cross_validate(lambda: GroupedMDE(group_column=2, **T1), X, y, traj, folds=4)
    assert mean.shape == std.shape == y.shape and torch.all(std > 0)
    # held out: a row's prediction does not come from a fit that saw its own label
    fitted_all = GroupedMDE(group_column=2, **T1).fit(X, y).predict(X)[0]
    assert (mean - y).abs().mean() > (fitted_all - y).abs().mean()
    with pytest.raises(ValueError, match="folds"):
        cross_validate(lambda: GroupedMDE(**T1), X, y, traj, folds=30)


@pytest.mark.parametrize("heteroscedastic", [False, True])
def test_covariance_is_gpytorchs_joint_latent_posterior(heteroscedastic) -> None:
    """mde covariance (what a look-ahead acquisition conditions on) against GPyTorch's own joint posterior; its
    diagonal is the latent variance of mean_var; groups are independent; before a fit, the iid prior."""
    X, y = _two_skills(120, 3)
    one = GPMDE(heteroscedastic=heteroscedastic, **T1).fit(X[X[:, 2] == 0], y[X[:, 2] == 0])
    Xq = X[X[:, 2] == 0][:6].clone()
    Xq[:, 0] += 0.01
    C = one.covariance(Xq, Xq[:4])
    joint = one.model.posterior(Xq.unsqueeze(0)).distribution.covariance_matrix[0]
    torch.testing.assert_close(C, joint[:, :4], rtol=1e-4, atol=1e-6 * float(joint.diagonal().max()))
    torch.testing.assert_close(one.covariance(Xq, Xq).diagonal(), one.mean_var(Xq, observation_noise=False)[1])
    g = GroupedMDE(group_column=2, heteroscedastic=heteroscedastic, **T1).fit(X, y)
    mixed = torch.cat([Xq[:3], X[X[:, 2] == 1][:2]])
    Cg = g.covariance(mixed, mixed)
    assert torch.all(Cg[:3, 3:] == 0) and torch.all(Cg[3:, :3] == 0)
    torch.testing.assert_close(Cg[:3, :3], g.covariance(Xq[:3], Xq[:3]))
    fresh = GroupedMDE(group_column=2, **T1)
    assert torch.equal(fresh.covariance(Xq[:2], Xq[:2]), torch.eye(2, dtype=torch.float64))
    assert torch.equal(g.marginal_model.covariance(mixed, mixed), Cg)
