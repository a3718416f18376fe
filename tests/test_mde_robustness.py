"""MDE input validation, degenerate data, factorisation failures and configuration."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import pytest
import torch
from linear_operator.utils.errors import NotPSDError

import mde.gp
from mde import GPMDE, GroupedMDE, MDEConfig
from mde.gp import safe_cholesky

T1 = {"num_threads": 1, "max_iters": 2}  # see tests/test_mde_model.py
ROOT = Path(__file__).resolve().parents[1]


def _data(n: int = 30, d: int = 2, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    X = torch.rand(n, d, generator=g, dtype=torch.float64)
    y = (0.5 + X.sum(dim=1) + 0.1 * torch.randn(n, generator=g, dtype=torch.float64)).clamp_min(0.0)
    return X, y


@pytest.mark.parametrize(
    "X, y, match",
    [
        (torch.rand(5, dtype=torch.float64), torch.rand(5, dtype=torch.float64), "2-D"),
        (torch.rand(2, 5, 3, dtype=torch.float64), torch.rand(2, dtype=torch.float64), "2-D"),
        (torch.rand(5, 2, dtype=torch.float64), torch.rand(4, dtype=torch.float64), "length mismatch"),
        (torch.rand(5, 2, dtype=torch.float64), torch.rand(5, 2, dtype=torch.float64), "1-D"),
        (torch.tensor([[0.0, float("nan")], [1.0, 2.0]]), torch.ones(2), "X contains NaN or inf"),
        (torch.tensor([[0.0, float("inf")], [1.0, 2.0]]), torch.ones(2), "X contains NaN or inf"),
        (torch.rand(2, 2), torch.tensor([1.0, float("inf")]), "y contains NaN or inf"),
        (torch.rand(2, 2), torch.tensor([1.0, float("nan")]), "y contains NaN or inf"),
        (torch.rand(2, 2), torch.tensor([1.0, -0.5]), "non-negative"),
        (torch.rand(2, 0), torch.rand(2), "at least one feature"),
    ],
)
def test_fit_rejects_bad_input(X, y, match):
    with pytest.raises(ValueError, match=match):
        GPMDE().fit(X, y)


def test_predict_rejects_bad_input():
    X, y = _data()
    m = GPMDE(heteroscedastic=False, **T1).fit(X, y)
    with pytest.raises(ValueError, match="2-D"):
        m.predict(X[0])
    with pytest.raises(ValueError, match="d=3 features but the MDE was fitted with d=2"):
        m.predict(torch.rand(4, 3, dtype=torch.float64))
    with pytest.raises(ValueError, match="NaN or inf"):
        m.predict(torch.tensor([[0.1, float("nan")]], dtype=torch.float64))


def _check_consistent(m: GPMDE, Xq: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    mean, std = m.predict(Xq)
    assert torch.isfinite(mean).all() and torch.isfinite(std).all() and (std > 0).all()
    post = m.model.posterior(Xq.unsqueeze(1), observation_noise=True)
    torch.testing.assert_close(post.mean.reshape(-1), mean, rtol=1e-6, atol=1e-8)
    return mean, std


@pytest.mark.parametrize("heteroscedastic", [True, False])
def test_duplicate_inputs(heteroscedastic):
    X, y = _data(15)
    g = torch.Generator().manual_seed(1)
    X2 = torch.cat([X, X, X])  # every input three times, different labels
    y2 = (y.repeat(3) + 0.05 * torch.randn(45, generator=g, dtype=torch.float64)).clamp_min(0.0)
    m = GPMDE(heteroscedastic=heteroscedastic, predict_dtype="float64", **T1).fit(X2, y2)
    assert m.is_fitted and m.n_train == 45
    _check_consistent(m, X)


@pytest.mark.parametrize("heteroscedastic", [True, False])
@pytest.mark.parametrize("value", [0.0, 0.05])
def test_constant_labels(heteroscedastic, value):
    X, _ = _data(20)
    y = torch.full((20,), value, dtype=torch.float64)
    m = GPMDE(heteroscedastic=heteroscedastic, predict_dtype="float64", **T1).fit(X, y)
    mean, std = _check_consistent(m, X)
    assert float((mean - value).abs().max()) < 0.01 + 0.1 * value
    assert float(m.prior_mean_z) == pytest.approx(-value)  # sigma_z falls back to 1 for constant labels


@pytest.mark.parametrize("heteroscedastic", [True, False])
def test_single_point(heteroscedastic):
    X = torch.tensor([[0.2, 0.7]], dtype=torch.float64)
    y = torch.tensor([0.3], dtype=torch.float64)
    m = GPMDE(heteroscedastic=heteroscedastic, predict_dtype="float64", **T1).fit(X, y)
    mean, std = _check_consistent(m, torch.cat([X, X + 100.0]))
    assert 0.0 <= float(mean[0]) <= 0.3 + 1e-9  # shrunk towards the zero-deviation prior
    assert abs(float(mean[1])) < 1e-6  # far away: the prior


def test_refit_on_empty_data_returns_to_prior():
    X, y = _data()
    m = GPMDE(heteroscedastic=False, **T1).fit(X, y)
    m.fit(X[:0], y[:0])
    assert not m.is_fitted
    mean, std = m.predict(X)
    assert torch.equal(mean, torch.zeros(30, dtype=torch.float64))
    assert torch.equal(std, torch.full((30,), m.config.prior_std, dtype=torch.float64))


def test_safe_cholesky_adds_jitter_then_gives_up():
    K = torch.ones(4, 4, dtype=torch.float64)  # PSD, singular
    with pytest.warns(RuntimeWarning, match="jitter"):
        L = safe_cholesky(K, jitter=1e-6, max_tries=4)
    assert torch.allclose(L @ L.T, K, atol=1e-4)
    with pytest.raises(NotPSDError, match=r"not positive definite even with jitter up to 1\.00e-04"):  # 1e-6 * 10^2
        safe_cholesky(-torch.eye(3, dtype=torch.float64), jitter=1e-6, max_tries=3)
    with pytest.raises(NotPSDError, match="NaN"):
        safe_cholesky(torch.full((2, 2), float("nan"), dtype=torch.float64))


def _always_fails(K, jitter=1e-6, max_tries=4):
    raise NotPSDError("forced failure for the test")


_IGNORE_BOTORCH = "ignore::botorch.exceptions.warnings.OptimizationWarning"  # botorch's own report


@pytest.mark.filterwarnings(_IGNORE_BOTORCH)
def test_factorisation_failure_keeps_previous_fit(monkeypatch):
    X, y = _data()
    m = GPMDE(**T1).fit(X, y)
    before = m.predict(X)
    monkeypatch.setattr(mde.gp, "safe_cholesky", _always_fails)
    X2, y2 = _data(40, seed=5)
    with pytest.warns(RuntimeWarning, match="keeping the previous fit"):
        m.fit(X2, y2)
    assert m.n_train == 30
    after = m.predict(X)
    assert torch.equal(before[0], after[0]) and torch.equal(before[1], after[1])


@pytest.mark.filterwarnings(_IGNORE_BOTORCH)
def test_factorisation_failure_without_previous_fit_keeps_prior(monkeypatch):
    monkeypatch.setattr(mde.gp, "safe_cholesky", _always_fails)
    X, y = _data()
    with pytest.warns(RuntimeWarning, match="keeping the prior"):
        m = GPMDE(**T1).fit(X, y)
    assert not m.is_fitted
    assert torch.equal(m.predict(X)[1], torch.ones(30, dtype=torch.float64))


@pytest.mark.filterwarnings(_IGNORE_BOTORCH)
def test_noise_model_failure_falls_back_to_the_homoscedastic_gp(monkeypatch):
    """Seen in the quick experiment: 27 pours, most labels near 0 and a few of 0.4-0.7, made the
    log-noise GP singular. The fit must not be lost: the homoscedastic GP is used instead."""
    import mde.model

    real = mde.model.fit_gp

    def noise_fit_fails(model, **kw):
        if not isinstance(model, mde.gp.MDEGP):  # the log-noise GP is a plain SingleTaskGP
            raise NotPSDError("forced failure of the noise model")
        return real(model, **kw)

    monkeypatch.setattr(mde.model, "fit_gp", noise_fit_fails)
    X, y = _data()
    with pytest.warns(RuntimeWarning, match="using the homoscedastic GP"):
        m = GPMDE(**T1).fit(X, y)
    assert m.is_fitted and m.noise_model is None and "noise model" in m.fit_info["heteroscedastic_error"]
    monkeypatch.setattr(mde.model, "fit_gp", real)
    homo = GPMDE(**T1, heteroscedastic=False).fit(X, y)
    assert torch.equal(m.predict(X)[0], homo.predict(X)[0])


@pytest.mark.parametrize(
    "field, value, match",
    [
        ("nu", 2.0, r"nu must be one of \(0.5, 1.5, 2.5\)"),
        ("nu", "2.5", "nu must be one of"),
        ("heteroscedastic", "yes", "heteroscedastic must be true or false"),
        ("input_scaling", "zscore", r"input_scaling must be one of \('none', 'normalize'\)"),
        ("predict_dtype", "float16", "predict_dtype must be one of"),
        ("prior_std", 0.0, "prior_std must be a finite number > 0"),
        ("prior_std", float("nan"), "prior_std must be a finite number > 0"),
        ("noise_floor", -1e-3, "noise_floor must be a finite number > 0"),
        ("jitter", 0, "jitter must be a finite number > 0"),
        ("max_iters", 0, "max_iters must be an integer >= 1"),
        ("max_iters", 2.5, "max_iters must be an integer >= 1"),
        ("fit_maxiter", 0, "fit_maxiter must be an integer >= 1"),
        ("max_fit_points", 1, "max_fit_points must be 0"),
        ("min_improvement", -1.0, "min_improvement must be a finite number >= 0"),
        ("num_threads", -1, "num_threads must be an integer >= 0"),
        ("predict_chunk", 0, "predict_chunk must be an integer >= 1"),
    ],
)
def test_config_validation_names_field_and_allowed_values(field, value, match):
    with pytest.raises(ValueError, match=match):
        MDEConfig(**{field: value})
    with pytest.raises(ValueError, match=match):
        GPMDE(**{field: value})


def test_config_unknown_key_and_mapping():
    with pytest.raises(ValueError, match="unknown MDE config field"):
        MDEConfig.from_dict({"nu": 2.5, "lengthscale": 1.0})
    cfg = MDEConfig.from_dict({"_target_": "mde.GPMDE", "nu": 1.5})
    assert cfg.nu == 1.5
    assert GPMDE({"heteroscedastic": False}, nu=0.5).config == MDEConfig(heteroscedastic=False, nu=0.5)


def test_yaml_lists_exactly_the_dataclass_fields_with_its_defaults():
    import yaml

    path = ROOT / "configs" / "mde" / "default.yaml"
    raw = yaml.safe_load(path.read_text())
    assert raw.pop("_target_") == "mde.GroupedMDE"
    assert set(raw) == {f.name for f in fields(MDEConfig)}
    # the library's defaults (the paper's GP), except that the task groups by the action's skill (one GP per skill)
    # and fits one noise level per skill on labels capped at 0.1 (configs/mde/default.yaml)
    assert MDEConfig.from_yaml(path) == MDEConfig(group_column=5, heteroscedastic=False, label_max=0.1)


def test_hydra_instantiate():
    pytest.importorskip("hydra")
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    cfg = OmegaConf.load(ROOT / "configs" / "mde" / "default.yaml")
    cfg.heteroscedastic = False
    m = instantiate(cfg)
    assert isinstance(m, GroupedMDE) and m.config.heteroscedastic is False and m.config.group_column == 5
    cfg.update({"_target_": "mde.GPMDE", "group_column": None})
    assert isinstance(instantiate(cfg), GPMDE)
