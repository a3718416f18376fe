"""The model deviation estimator: a GP on BoTorch, with homoscedastic or most-likely heteroscedastic noise.

The MDE predicts a Gaussian over the deviation d(f_hat(s, a), s') of the learned dynamics model
from the target world, given features X = (s, a). The planner uses ``mu + beta * sigma < d_max``,
so both the mean and a calibrated predictive std matter. The paper's MDE lets the std grow where the
data is noisy (pours near the plant): heteroscedastic noise (``heteroscedastic: true``). With
``heteroscedastic: false`` the GP has one noise level (step 1 below alone).

BoTorch >= 0.13 has no heteroscedastic GP, so this follows Kersting et al. (2007), "Most likely
heteroscedastic Gaussian process regression":

1. fit a homoscedastic GP G1 on the z-scored labels;
2. empirical noise at each training point: ``E_f[(y_i - f_i)^2] = r_i^2 + v_i`` (in-sample
   residual and latent posterior variance, the closed form of Kersting's sample average), with
   the residual term scaled by ``exp(1.27)``: the log of one squared Gaussian residual is biased
   low by ``E[log chi^2_1] = -1.27``, which would otherwise shrink the noise by a factor ~3.6;
3. fit a noise GP G3 on the log of that noise;
4. fit the mean GP G2 with fixed per-point noise ``exp(G3 mean)`` (floored);
5. repeat 2-4 from G2 until its log marginal likelihood stops improving; keep the best.

At prediction the noise comes from G3 out of sample. Labels are z-scored by BoTorch's
``Standardize`` and the GP prior mean is fixed at ``-mu_z / sigma_z`` (zero deviation), so away
from the data the MDE predicts zero deviation with a wide std, as in the paper.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import torch
from botorch.exceptions.errors import ModelFittingError
from botorch.models import SingleTaskGP
from botorch.models.model import Model
from botorch.posteriors import Posterior
from linear_operator.utils.errors import NanError, NotPSDError
from torch import Tensor

import safeio
from task.threads import torch_threads

from .config import MDEConfig
from .gp import (
    DTYPE,
    MDEGP,
    MarginalModel,
    PriorMDEModel,
    build_mean_gp,
    build_noise_gp,
    data_bounds,
    fit_gp,
    iid_covariance,
    safe_cholesky,
    train_inputs_transformed,
)
from .kernel_cache import AffineMean, KernelCache

#: ``-E[log chi^2_1] = Euler's gamma + log 2``: bias of the log of one squared standard Gaussian.
LOG_CHI2_BIAS = 0.5772156649015329 + math.log(2.0)
_FORMAT = "mde.GPMDE"
_FORMAT_VERSION = 1
_FIT_ERRORS = (NotPSDError, NanError, ModelFittingError, torch.linalg.LinAlgError)


@dataclass
class _Fitted:
    """Everything that describes one successful fit (swapped in atomically on success)."""

    X: Tensor
    y: Tensor
    bounds: Tensor | None
    mean_model: MDEGP
    train_Yvar: Tensor | None  # label units, None for the homoscedastic GP
    noise_model: SingleTaskGP | None
    noise_train: tuple[Tensor, Tensor] | None  # raw (X, log noise) the noise GP was built on
    mu_z: float
    sigma_z: float
    mean_cache: KernelCache
    noise_cache: KernelCache | None
    noise_affine: tuple[float, float]  # log-noise GP outcome transform (mean, std)
    const_noise_z: float  # homoscedastic noise (z units); unused when noise_cache is set
    info: dict[str, Any] = field(default_factory=dict)


class GPMDE:
    """Model deviation estimator, one GP: ``fit(X, y)``, ``predict(X) -> (mean, std)``, BoTorch ``model``.

    Args:
        config: an :class:`MDEConfig` or a mapping of its fields (e.g. a Hydra node).
        **overrides: individual fields, e.g. ``GPMDE(heteroscedastic=False)``.

    ``predict`` returns the predictive distribution of the deviation in label units: std includes
    both the latent GP variance and the noise at X (the noise GP's, when heteroscedastic). ``model.posterior(X)`` is the
    latent posterior in label units; ``model.posterior(X, observation_noise=True)`` equals
    ``predict``. Before any data both give mean 0 and std ``config.prior_std``.
    """

    def __init__(self, config: MDEConfig | Mapping[str, Any] | None = None, **overrides: Any) -> None:
        if isinstance(config, MDEConfig):
            base = config.to_dict()
        else:
            base = MDEConfig.from_dict(config).to_dict()
        base.update(overrides)
        self._config = MDEConfig.from_dict(base)
        if self._config.group_column is not None:
            raise ValueError(
                f"group_column={self._config.group_column}: GPMDE is one GP for all rows; "
                "use mde.GroupedMDE for one GP per group (or group_column=null)"
            )
        self._fitted: _Fitted | None = None
        self._n_features: int | None = None
        self._prior_model = PriorMDEModel(self._config.prior_std)

    # -- properties ------------------------------------------------------------------------------
    @property
    def config(self) -> MDEConfig:
        return self._config

    @property
    def is_fitted(self) -> bool:
        """True once fitted on at least one point (otherwise predictions are the prior)."""
        return self._fitted is not None

    @property
    def n_train(self) -> int:
        return 0 if self._fitted is None else int(self._fitted.X.shape[0])

    @property
    def n_features(self) -> int | None:
        """Input dimension fixed by the last ``fit`` (None before any fit)."""
        return self._n_features

    @property
    def train_X(self) -> Tensor | None:
        return None if self._fitted is None else self._fitted.X

    @property
    def train_y(self) -> Tensor | None:
        return None if self._fitted is None else self._fitted.y

    @property
    def label_mean(self) -> float:
        """mu_z of the z-scoring (0 before fit)."""
        return 0.0 if self._fitted is None else self._fitted.mu_z

    @property
    def label_std(self) -> float:
        """sigma_z of the z-scoring (1 before fit)."""
        return 1.0 if self._fitted is None else self._fitted.sigma_z

    @property
    def prior_mean_z(self) -> float:
        """GP prior mean in z-scored units: ``-mu_z / sigma_z`` (0 before fit)."""
        return 0.0 if self._fitted is None else float(self._fitted.mean_model.mean_module.constant)

    @property
    def model(self) -> Model:
        """BoTorch model whose posterior is in label units (see class docstring)."""
        return self._prior_model if self._fitted is None else self._fitted.mean_model

    @property
    def marginal_model(self) -> MarginalModel:
        """BoTorch view of :meth:`mean_var` (per-row marginals, the fit's cached factorisation): what the
        acquisitions read, so that they never refactorise a kernel the fit accepted (see :attr:`model` for
        the full GPyTorch posterior)."""
        return MarginalModel(self)

    @property
    def noise_model(self) -> SingleTaskGP | None:
        """GP on the log noise variance (label units), None unless heteroscedastic and fitted."""
        return None if self._fitted is None else self._fitted.noise_model

    @property
    def fit_info(self) -> dict[str, Any]:
        """Diagnostics of the last successful fit (log ML history, times, sizes)."""
        return {} if self._fitted is None else dict(self._fitted.info)

    # -- fitting ---------------------------------------------------------------------------------
    def fit(self, X: Any, y: Any) -> "GPMDE":
        """Fit on the whole dataset (not incremental). ``X``: n x d, ``y``: n deviations >= 0.

        n = 0 resets to the prior. If the GP cannot be factorised even with jitter, a warning is
        issued and the previous fit (or the prior) is kept, so that a long active-learning run
        survives one bad batch of data.
        """
        X = _as_matrix(X, "X").to(DTYPE)
        y = _as_labels(y, X.shape[0])
        if self._config.label_max is not None:  # the labels as fitted (and as train_y reports them)
            y = y.clamp(max=self._config.label_max)
        if self._n_features is not None and self._fitted is not None and X.shape[1] != self._n_features:
            warnings.warn(
                f"refitting with d={X.shape[1]} features; previous fit had d={self._n_features}",
                RuntimeWarning,
                stacklevel=2,
            )
        if X.shape[0] == 0:
            self._fitted = None
            self._n_features = int(X.shape[1])
            return self
        try:
            with torch_threads(self._config.num_threads):
                fitted = self._fit(X, y)
        except _FIT_ERRORS as err:
            what = "previous fit" if self._fitted is not None else "prior"
            msg = f"MDE fit on {X.shape[0]} points failed ({err}); keeping the {what}"
            warnings.warn(msg, RuntimeWarning, stacklevel=2)
            return self
        self._fitted = fitted
        self._n_features = int(X.shape[1])
        return self

    def _fit(self, X: Tensor, y: Tensor) -> _Fitted:
        cfg = self._config
        t0 = time.perf_counter()
        n = X.shape[0]
        bounds = data_bounds(X) if cfg.input_scaling == "normalize" else None
        subset = None
        if cfg.max_fit_points and n > cfg.max_fit_points:
            gen = torch.Generator().manual_seed(cfg.seed)
            subset = torch.randperm(n, generator=gen)[: cfg.max_fit_points].sort().values
        Xf, yf = (X, y) if subset is None else (X[subset], y[subset])
        fit_kw = dict(maxiter=cfg.fit_maxiter, jitter=cfg.jitter, max_tries=cfg.max_jitter_tries)
        build_kw = dict(
            nu=cfg.nu,
            bounds=bounds,
            noise_floor=cfg.noise_floor,
            lengthscale_max=cfg.lengthscale_max,
            latent_std_min=cfg.latent_std_min,
            latent_std_max=cfg.latent_std_max,
            priors=cfg.hyperparameter_priors,
        )

        homo = build_mean_gp(Xf, yf, **build_kw)
        homo_ml = fit_gp(homo, **fit_kw)
        info: dict[str, Any] = {
            "n": int(n),
            "n_fit_points": int(Xf.shape[0]),
            "heteroscedastic": bool(cfg.heteroscedastic),
            "homoscedastic_log_ml": homo_ml,
            "log_ml_history": [],
            "selected_iteration": 0,
        }
        noise_model: SingleTaskGP | None = None
        noise_train: tuple[Tensor, Tensor] | None = None
        train_Yvar: Tensor | None = None
        mean_model: MDEGP = homo
        if cfg.heteroscedastic:
            mean_model, noise_model, train_Yvar, noise_train = self._most_likely_loop(
                Xf, yf, homo, info, build_kw, fit_kw
            )
        if subset is not None:  # condition on all points with the hyperparameters of the subset
            mean_model, train_Yvar = self._condition_on_all(X, y, mean_model, noise_model, build_kw)
        if noise_model is not None:
            mean_model.set_noise_model(noise_model)
        mean_model.eval()
        mean_model.requires_grad_(False)
        info["fit_seconds"] = time.perf_counter() - t0
        return self._make_fitted(X, y, bounds, mean_model, train_Yvar, noise_model, noise_train, info)

    def _most_likely_loop(self, X, y, homo, info, build_kw, fit_kw):
        cfg = self._config
        sigma2 = float(homo.outcome_transform.stdvs) ** 2
        current: MDEGP = homo
        prev_noise: SingleTaskGP | None = None
        best = None
        for it in range(1, cfg.max_iters + 1):
            try:
                log_noise = _empirical_log_noise(current, cfg) + math.log(sigma2)  # label units
                noise_gp = build_noise_gp(
                    X,
                    log_noise,
                    nu=cfg.nu,
                    bounds=build_kw["bounds"],
                    lengthscale_max=cfg.noise_lengthscale_bound,
                    priors=cfg.hyperparameter_priors,
                )
                if prev_noise is not None:  # warm start: later iterations move little
                    noise_gp.covar_module.load_state_dict(prev_noise.covar_module.state_dict())
                    noise_gp.likelihood.load_state_dict(prev_noise.likelihood.state_dict())
                fit_gp(noise_gp, **fit_kw)
                noise_z = _noise_at(noise_gp, X, sigma2, cfg)
                train_Yvar = noise_z * sigma2
                mean_gp = build_mean_gp(X, y, train_Yvar=train_Yvar, **build_kw)
                mean_gp.covar_module.load_state_dict(current.covar_module.state_dict())
                ml = fit_gp(mean_gp, **fit_kw)
            except _FIT_ERRORS as err:
                # a few extreme labels among many near-zero ones can make the log-noise GP singular;
                # keep the best iteration so far (or the homoscedastic GP), do not lose the whole fit
                info["heteroscedastic_error"] = f"iteration {it}: {err}"
                break
            info["log_ml_history"].append(ml)
            improved_by = math.inf if best is None else ml - best[3]
            if improved_by > 0:
                best = (mean_gp, noise_gp, train_Yvar, ml, it, log_noise)
            if improved_by <= cfg.min_improvement:
                break
            current, prev_noise = mean_gp, noise_gp
        if best is None:
            warnings.warn(
                f"MDE noise model failed on {X.shape[0]} points ({info['heteroscedastic_error']}); "
                "using the homoscedastic GP for this fit",
                RuntimeWarning,
                stacklevel=3,
            )
            info["selected_iteration"] = 0
            return homo, None, None, None
        info["selected_iteration"] = best[4]
        return best[0], best[1], best[2], (X, best[5])

    def _condition_on_all(self, X, y, fitted: MDEGP, noise_model, build_kw):
        train_Yvar = None
        if noise_model is not None:
            probe = build_mean_gp(X, y, **build_kw)  # only for the full data's z-scoring
            sigma2 = float(probe.outcome_transform.stdvs) ** 2
            train_Yvar = _noise_at(noise_model, X, sigma2, self._config) * sigma2
        model = build_mean_gp(X, y, train_Yvar=train_Yvar, **build_kw)
        model.covar_module.load_state_dict(fitted.covar_module.state_dict())
        if train_Yvar is None:
            model.likelihood.load_state_dict(fitted.likelihood.state_dict())
        return model, train_Yvar

    def _make_fitted(self, X, y, bounds, mean_model, train_Yvar, noise_model, noise_train, info) -> _Fitted:
        cfg = self._config
        dtype = torch.float32 if cfg.predict_dtype == "float32" else torch.float64
        cache_kw = dict(jitter=cfg.jitter, max_tries=cfg.max_jitter_tries, bounds=bounds)
        tf = mean_model.outcome_transform
        mu_z, sigma_z = float(tf.means), float(tf.stdvs)
        mean_cache = KernelCache(mean_model, cfg.nu, dtype, **cache_kw)
        noise_cache, affine, const_noise = None, (0.0, 1.0), 0.0
        if noise_model is not None:
            noise_cache = KernelCache(noise_model, cfg.nu, dtype, **cache_kw)
            ntf = noise_model.outcome_transform
            affine = (float(ntf.means), float(ntf.stdvs))
            mean_model.log_noise_fn = AffineMean(noise_cache, *affine)  # posterior reads predict's noise
        else:
            const_noise = float(mean_model.likelihood.noise.reshape(-1)[0])
        info = dict(info, label_mean=mu_z, label_std=sigma_z)
        return _Fitted(
            X=X, y=y, bounds=bounds, mean_model=mean_model, train_Yvar=train_Yvar,
            noise_model=noise_model, noise_train=noise_train, mu_z=mu_z, sigma_z=sigma_z, mean_cache=mean_cache,
            noise_cache=noise_cache, noise_affine=affine, const_noise_z=const_noise, info=info,
        )  # fmt: skip

    # -- prediction ------------------------------------------------------------------------------
    def predict(self, X: Any) -> tuple[Tensor, Tensor]:
        """Mean and std of the predicted deviation at ``X`` (n x d), label units, no autograd.

        The std is that of the predictive distribution (latent variance + noise at X). Output
        dtype follows ``X`` (float64 for non-float input).
        """
        mean, var_z, dtype = self._predict_z(X, observation_noise=True)
        if var_z is None:
            return mean, torch.full_like(mean, self._config.prior_std)
        return mean, var_z.sqrt_().mul_(self._fitted.sigma_z).to(dtype)

    def mean_var(self, X: Any, observation_noise: bool = True) -> tuple[Tensor, Tensor]:
        """Mean and variance (latent, plus the noise at ``X`` if ``observation_noise``), label units.

        The cached factorisation of the fit (with the jitter the fit accepted), so that planner and
        acquisition read one set of numbers: GPyTorch's own posterior refactorises the kernel with a
        smaller jitter cap and can fail on a fit this model accepted.
        """
        mean, var_z, dtype = self._predict_z(X, observation_noise)
        if var_z is None:
            return mean, torch.full_like(mean, self._config.prior_std**2)
        return mean, var_z.mul_(self._fitted.sigma_z**2).to(dtype)

    def covariance(self, Xa: Any, Xb: Any) -> Tensor:
        """Latent posterior covariance ``a x b`` (label units, float64) between the rows of ``Xa`` and ``Xb``.

        Before a fit the prior: iid with ``prior_std``, so identical rows covary and others do not. With
        ``mean_var(X, observation_noise=False)`` it gives the joint latent posterior that a look-ahead
        acquisition conditions on (:class:`active.acquisition.TrajectoryAdmissionGain`)."""
        Xa, Xb = self._check_query(Xa), self._check_query(Xb)
        f = self._fitted
        if f is None:
            return iid_covariance(Xa, Xb, self._config.prior_std)
        with torch.no_grad(), torch_threads(self._config.num_threads):
            return f.mean_cache.covariance(Xa, Xb).mul_(f.sigma_z**2)

    def _predict_z(self, X: Any, observation_noise: bool) -> tuple[Tensor, Tensor | None, torch.dtype]:
        """Mean (label units, output dtype) and float64 variance in z-scored units (None before a fit)."""
        X = self._check_query(X)
        out_dtype = X.dtype
        f = self._fitted
        if f is None:
            return torch.zeros(X.shape[0], dtype=out_dtype), None, out_dtype
        means, variances = [], []
        with torch.no_grad(), torch_threads(self._config.num_threads):
            for chunk in X.split(self._config.predict_chunk):
                m_z, v_z = f.mean_cache.mean_var(chunk)
                v_z = v_z.to(torch.float64)
                if observation_noise:
                    v_z = v_z.add_(self._noise_z(chunk))
                means.append(m_z.mul_(f.sigma_z).add_(f.mu_z).to(out_dtype))
                variances.append(v_z)
        if len(means) == 1:
            return means[0], variances[0], out_dtype
        return torch.cat(means), torch.cat(variances), out_dtype

    def noise_std(self, X: Any) -> Tensor:
        """Std of the observation noise alone at ``X`` (label units), for diagnostics and plots."""
        X = self._check_query(X)
        if self._fitted is None:
            return torch.zeros(X.shape[0], dtype=X.dtype)
        with torch.no_grad():
            var_z = torch.as_tensor(self._noise_z(X), dtype=torch.float64).expand(X.shape[0])
            return (var_z.sqrt() * self._fitted.sigma_z).to(X.dtype)

    def _check_query(self, X: Any) -> Tensor:
        X = _as_matrix(X, "X")
        if self._n_features is not None and X.shape[1] != self._n_features:
            raise ValueError(f"X has d={X.shape[1]} features but the MDE was fitted with d={self._n_features}")
        return X

    def _noise_z(self, X: Tensor) -> Tensor | float:
        f = self._fitted
        if f.noise_cache is None:
            return f.const_noise_z
        # one home for the noise (cached mean, cap, floor): what the BoTorch posterior reads too
        return f.mean_model.noise_variance(X.to(torch.float64))

    def posterior(self, X: Tensor, observation_noise: bool = False) -> Posterior:
        """Shortcut for ``self.model.posterior`` (label units; see the class docstring)."""
        return self.model.posterior(X, observation_noise=observation_noise)

    # -- persistence -----------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> Path:
        """Write config, data and fitted state to ``path`` atomically (temp file + os.replace)."""
        return safeio.save_torch(Path(path), self.to_payload())

    def to_payload(self) -> dict[str, Any]:
        """Config, data and fitted state as tensors and plain types (what :meth:`save` writes)."""
        f = self._fitted
        payload: dict[str, Any] = {
            "format": _FORMAT,
            "version": _FORMAT_VERSION,
            "config": self._config.to_dict(),
            "n_features": self._n_features,
            "fitted": None,
        }
        if f is not None:
            payload["fitted"] = {
                "X": f.X,
                "y": f.y,
                "bounds": f.bounds,
                "train_Yvar": f.train_Yvar,
                "mean_state": f.mean_model.state_dict(),
                "noise_X": None if f.noise_train is None else f.noise_train[0],
                "noise_Y": None if f.noise_train is None else f.noise_train[1],
                "info": f.info,
            }
        return payload

    @classmethod
    def load(cls, path: str | os.PathLike) -> "GPMDE":
        """Rebuild a saved MDE; predictions are identical to the saved one's."""
        payload = torch.load(Path(path), map_location="cpu", weights_only=True)
        return cls.from_payload(payload, str(path))

    @classmethod
    def from_payload(cls, payload: Any, source: str = "payload") -> "GPMDE":
        """Inverse of :meth:`to_payload`."""
        if not isinstance(payload, dict) or payload.get("format") != _FORMAT:
            tag = payload.get("format") if isinstance(payload, dict) else None
            raise ValueError(f"{source} is not a saved {_FORMAT} (format tag {tag!r}); fit the MDE again")
        if payload.get("version") != _FORMAT_VERSION:
            raise ValueError(
                f"{source} has format version {payload.get('version')}, this code reads version "
                f"{_FORMAT_VERSION}; fit the MDE again"
            )
        mde = cls(payload["config"])
        mde._n_features = payload["n_features"]
        state = payload["fitted"]
        if state is None:
            return mde
        cfg = mde._config
        bounds = state["bounds"]
        noise_model = None
        if state["noise_X"] is not None:
            noise_model = build_noise_gp(
                state["noise_X"],
                state["noise_Y"],
                nu=cfg.nu,
                bounds=bounds,
                lengthscale_max=cfg.noise_lengthscale_bound,
                priors=cfg.hyperparameter_priors,
            )
        mean_model = build_mean_gp(  # the lengthscale bounds come back with the saved state
            state["X"],
            state["y"],
            nu=cfg.nu,
            bounds=bounds,
            noise_floor=cfg.noise_floor,
            train_Yvar=state["train_Yvar"],
            lengthscale_max=cfg.lengthscale_max,
            latent_std_min=cfg.latent_std_min,
            latent_std_max=cfg.latent_std_max,
            priors=cfg.hyperparameter_priors,
        )
        if noise_model is not None:
            mean_model.set_noise_model(noise_model)  # a submodule: its state is in mean_state
        mean_model.load_state_dict(state["mean_state"])
        mean_model.eval()
        mean_model.requires_grad_(False)
        noise_train = None if noise_model is None else (state["noise_X"], state["noise_Y"])
        mde._fitted = mde._make_fitted(
            state["X"], state["y"], bounds, mean_model, state["train_Yvar"], noise_model, noise_train, state["info"]
        )
        return mde

    def __repr__(self) -> str:
        kind = "heteroscedastic" if self._config.heteroscedastic else "homoscedastic"
        return f"GPMDE({kind}, nu={self._config.nu}, n_train={self.n_train}, d={self._n_features})"


# -- helpers ---------------------------------------------------------------------------------------
def _empirical_log_noise(model: MDEGP, cfg: MDEConfig) -> Tensor:
    """log of ``exp(1.27) r_i^2 + v_i`` at the training points, z-scored units (see module doc)."""
    with torch.no_grad():
        X_t = train_inputs_transformed(model)
        n = X_t.shape[0]
        noise = model.likelihood.noise.detach().reshape(-1).expand(n)
        K = model.covar_module(X_t).to_dense() + torch.diag_embed(noise)
        L = safe_cholesky(K, cfg.jitter, cfg.max_jitter_tries)
        y = model.train_targets
        alpha = torch.cholesky_solve((y - model.mean_module.constant).unsqueeze(-1), L).squeeze(-1)
        L_inv = torch.linalg.solve_triangular(L, torch.eye(n, dtype=L.dtype), upper=False)
        K_inv_diag = (L_inv * L_inv).sum(dim=0)
        resid = noise * alpha  # y - posterior mean at the training points
        latent_var = (noise - noise * noise * K_inv_diag).clamp_min(0.0)
        e = math.exp(LOG_CHI2_BIAS) * resid * resid + latent_var
        return e.clamp_min(cfg.noise_floor).log()


def _noise_at(noise_model: SingleTaskGP, X: Tensor, sigma2: float, cfg: MDEConfig) -> Tensor:
    """Noise variance (z-scored units, floored) predicted by the log-noise GP at ``X``."""
    with torch.no_grad():
        bounds = _bounds_of(noise_model)
        kw = dict(jitter=cfg.jitter, max_tries=cfg.max_jitter_tries, bounds=bounds)
        cache = KernelCache(noise_model, cfg.nu, DTYPE, **kw)
        tf = noise_model.outcome_transform
        log_noise = cache.mean(X) * float(tf.stdvs) + float(tf.means)
        return (log_noise.exp() / sigma2).clamp_min(cfg.noise_floor)


def _bounds_of(model: SingleTaskGP) -> Tensor | None:
    tf = getattr(model, "input_transform", None)
    if tf is None:
        return None
    lo = tf.offset.reshape(-1)
    return torch.stack([lo, lo + tf.coefficient.reshape(-1)])


def _as_matrix(X: Any, name: str) -> Tensor:
    """Validate features: a finite 2-D float tensor (float64 if given non-float data)."""
    X = torch.as_tensor(X)
    if not X.is_floating_point():
        X = X.to(DTYPE)
    if X.dim() != 2:
        raise ValueError(f"{name} must be 2-D (n x d), got shape {tuple(X.shape)}")
    if X.shape[1] == 0:
        raise ValueError(f"{name} must have at least one feature column, got shape {tuple(X.shape)}")
    if not torch.isfinite(X).all():
        bad = (~torch.isfinite(X)).any(dim=1).nonzero().reshape(-1)[:5].tolist()
        raise ValueError(f"{name} contains NaN or inf (rows {bad}...)")
    return X.detach().cpu()


def _as_labels(y: Any, n: int) -> Tensor:
    """Validate labels: n finite non-negative deviations (n or n x 1)."""
    y = torch.as_tensor(y)
    if not y.is_floating_point():
        y = y.to(DTYPE)
    if y.dim() == 2 and y.shape[1] == 1:
        y = y.reshape(-1)
    if y.dim() != 1:
        raise ValueError(f"y must be 1-D (n,) or n x 1, got shape {tuple(y.shape)}")
    if y.shape[0] != n:
        raise ValueError(f"X has {n} rows but y has {y.shape[0]} labels (length mismatch)")
    if not torch.isfinite(y).all():
        raise ValueError("y contains NaN or inf")
    if (y < 0).any():
        raise ValueError(f"y must be non-negative deviations, got min {float(y.min()):.3g}")
    return y.detach().cpu().to(DTYPE)
