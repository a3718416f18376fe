"""BoTorch / GPyTorch building blocks of the MDE: the GP models, their fitting, a safe Cholesky.

Why a custom loss closure: GPyTorch's exact marginal likelihood backpropagates through its
Cholesky factorisation, which costs about three times more than the closed-form gradient
``dNLL/dK = (K^-1 - alpha alpha^T) / 2``. The closure below computes exactly the same objective as
``ExactMarginalLogLikelihood`` (including the log density of any hyperparameter priors the model
carries) and is handed to BoTorch's ``fit_gpytorch_mll``, which still does the L-BFGS-B
optimisation, parameter bounds and retries. A test checks the two objectives agree.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import gpytorch
import torch
from botorch.exceptions.warnings import InputDataWarning, OptimizationWarning
from botorch.fit import DEFAULT_WARNING_HANDLER, fit_gpytorch_mll
from botorch.models import SingleTaskGP
from botorch.models.model import Model
from botorch.models.transforms.input import Normalize
from botorch.models.transforms.outcome import Standardize
from botorch.optim.closures import ForwardBackwardClosure
from botorch.optim.utils import get_parameters_and_bounds
from botorch.posteriors.gpytorch import GPyTorchPosterior
from gpytorch.constraints import GreaterThan, Interval
from gpytorch.distributions import MultivariateNormal
from gpytorch.kernels import MaternKernel, ScaleKernel
from gpytorch.likelihoods import GaussianLikelihood
from gpytorch.means import ConstantMean
from gpytorch.mlls import ExactMarginalLogLikelihood
from gpytorch.priors import GammaPrior, LogNormalPrior
from linear_operator.operators import DiagLinearOperator
from linear_operator.utils.errors import NanError, NotPSDError
from torch import Tensor

from mde.config import ALLOWED_PRIORS

DTYPE = torch.float64
#: Box for raw hyperparameters during fitting: softplus(-25) ~ 1e-11, softplus(1e5) = 1e5.
RAW_LOWER, RAW_UPPER = -25.0, 1e5
_LOG_2PI = math.log(2.0 * math.pi)


# -- linear algebra --------------------------------------------------------------------------------
def safe_cholesky(K: Tensor, jitter: float = 1e-6, max_tries: int = 4) -> Tensor:
    """Cholesky factor of ``K``; on failure retry with jitter ``jitter * mean(diag) * 10^k``.

    Raises ``NotPSDError`` when every retry fails, so that callers can keep a previous fit.
    """
    L, info = torch.linalg.cholesky_ex(K)
    if not bool(torch.any(info)):
        return L
    if not torch.isfinite(K).all():
        raise NotPSDError("covariance matrix contains NaN or inf")
    scale = K.diagonal(dim1=-2, dim2=-1).abs().mean().clamp_min(1e-12)
    eye = torch.eye(K.shape[-1], dtype=K.dtype, device=K.device)
    for k in range(max_tries):
        eps = float(scale) * jitter * (10.0**k)
        L, info = torch.linalg.cholesky_ex(K + eps * eye)
        if not bool(torch.any(info)):
            warnings.warn(f"Cholesky needed jitter {eps:.2e} to succeed", RuntimeWarning, stacklevel=2)
            return L
    raise NotPSDError(f"matrix is not positive definite even with jitter up to {eps:.2e}")


def _matern_scale(nu: float) -> float:
    return {0.5: 1.0, 1.5: math.sqrt(3.0), 2.5: math.sqrt(5.0)}[nu]


def matern_parts(r: Tensor, nu: float) -> tuple[Tensor, Tensor, Tensor]:
    """``(K0, a, E)``: Matern correlation of scaled distances ``r`` (``|x - x'| / lengthscale``),
    with ``a = sqrt(2 nu) r`` and ``E = exp(-a)`` kept for the gradient. ``r`` is overwritten.

    In-place where possible: at n = 1200 each ``n x n`` float64 temporary costs milliseconds.
    """
    a = r.mul_(_matern_scale(nu))
    E = torch.exp(-a)
    if nu == 0.5:
        return E, a, E
    if nu == 1.5:
        K0 = a + 1.0
    else:
        K0 = a * a
        K0.div_(3.0).add_(a).add_(1.0)
    return K0.mul_(E), a, E


def matern_from_dist(r: Tensor, nu: float) -> Tensor:
    """Matern correlation of scaled distances ``r`` (not modified)."""
    return matern_parts(r.clone(), nu)[0]


def _matern_dk_over_r(a: Tensor, E: Tensor, nu: float) -> Tensor:
    """``k'(r) / r`` from ``a = sqrt(2 nu) r`` and ``E = exp(-a)`` (0 at r = 0 for nu = 0.5)."""
    if nu == 0.5:
        return torch.where(a > 0, -E / a.clamp_min(1e-300), torch.zeros_like(a))
    if nu == 1.5:
        return E * -3.0
    out = a + 1.0
    return out.mul_(E).mul_(-5.0 / 3.0)


def scaled_dist(Z: Tensor) -> Tensor:
    """Pairwise distances of the rows of ``Z`` from explicit differences (exact zeros on the diagonal).

    Why not ``|z|^2 + |z'|^2 - 2 z.z'`` (a matmul): with a lengthscale of ~1e-10 on a feature that barely
    varies (a volume fraction that is 1.000 or 0.974 over a skill's first points, seen on simulator data)
    the scaled coordinates reach ~1e8 and the matmul form loses the other features' O(1) terms to
    cancellation, so rows equal in that feature got distances of order 1 and the kernel matrix stopped being
    positive definite: the fit failed and the MDE kept its prior. Differences are exact, and at d = 8 no
    slower (``torch.cdist`` without the matmul path: 9.9 against 12.2 ms at n = 2,000).
    """
    return torch.cdist(Z, Z, compute_mode="donot_use_mm_for_euclid_dist")


class _MaternGPNLL(torch.autograd.Function):
    """NLL of a constant-mean, ARD-Matern ScaleKernel GP with diagonal noise; closed-form grads.

    ``0.5 r^T K^-1 r + 0.5 log|K| + n/2 log 2 pi`` with ``K = s k(X / l) + diag(noise)`` and
    ``r = y - c``. Backward uses ``dNLL/dK = (K^-1 - alpha alpha^T) / 2`` and contracts it with the
    kernel derivatives directly, instead of backpropagating through the Cholesky factorisation and
    a dozen ``n x n`` elementwise kernel ops: about 3x cheaper, same values (tested).
    """

    @staticmethod
    def forward(ctx, ls, outputscale, noise, const, X, y, nu, jitter, max_tries):  # type: ignore[override]
        n = y.shape[-1]
        Z = (X - X.mean(dim=0)) / ls
        K0, a, E = matern_parts(scaled_dist(Z), nu)
        K = K0 * outputscale
        K.diagonal().add_(noise.expand(n))
        # A failure here is usually an extreme trial point of the line search: NanError makes
        # BoTorch hand NaN to L-BFGS-B, which backtracks (NotPSDError would abort the attempt).
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # jitter in a line search is normal
                L = safe_cholesky(K, jitter, max_tries)
        except NotPSDError as err:
            raise NanError(str(err)) from err
        del K
        resid = y - const
        alpha = torch.cholesky_solve(resid.unsqueeze(-1), L).squeeze(-1)
        nll = 0.5 * (resid @ alpha) + torch.log(torch.diagonal(L)).sum() + 0.5 * n * _LOG_2PI
        if not torch.isfinite(nll):
            raise NanError("non-finite marginal likelihood at these hyperparameters")
        ctx.save_for_backward(Z, a, E, K0, L, alpha, ls, outputscale)
        ctx.nu = nu
        ctx.noise_shape = noise.shape
        return nll

    @staticmethod
    def backward(ctx, grad):  # type: ignore[override]
        Z, a, E, K0, L, alpha, ls, outputscale = ctx.saved_tensors
        need_ls, need_os, need_noise, need_c = ctx.needs_input_grad[:4]
        # K^-1 via cholesky_solve: torch.cholesky_inverse (LAPACK potri) is faster at best but
        # erratic with 2 threads on a loaded CPU (up to seconds at n = 1200); this is steady.
        eye = torch.eye(L.shape[-1], dtype=L.dtype, device=L.device)
        W = torch.cholesky_solve(eye, L)
        W.addr_(alpha, alpha, alpha=-1.0).mul_(0.5 * grad)  # dNLL/dK = (K^-1 - alpha alpha^T) / 2
        d_ls = d_os = d_noise = d_c = None
        if need_os:
            d_os = torch.dot(W.reshape(-1), K0.reshape(-1))
        if need_noise:
            diag = W.diagonal()
            d_noise = diag.sum().reshape(ctx.noise_shape) if ctx.noise_shape.numel() == 1 else diag.clone()
        if need_c:
            d_c = -grad * alpha.sum()
        if need_ls:
            # dK/dl_j = s k'(r)/r * (-(dz_j)^2 / l_j);  sum_ab G_ab (z_aj - z_bj)^2 with G symmetric
            # equals 2 sum_a z_aj^2 rowsum(G)_a - 2 z_j^T G z_j.
            G = W.mul_(_matern_dk_over_r(a, E, ctx.nu)).mul_(outputscale)
            rows = G.sum(dim=1)
            S = 2.0 * ((Z * Z) * rows.unsqueeze(1)).sum(dim=0) - 2.0 * (Z * (G @ Z)).sum(dim=0)
            d_ls = (-S / ls).reshape(ls.shape)
        return d_ls, d_os, d_noise, d_c, None, None, None, None, None


def train_inputs_transformed(model: SingleTaskGP) -> Tensor:
    """Training inputs in the space the kernel sees (after the optional input transform)."""
    X = getattr(model, "_original_train_inputs", None)
    X = model.train_inputs[0] if X is None or model.training else X
    tf = getattr(model, "input_transform", None)
    if tf is None:
        return X
    was_training = tf.training
    tf.train()  # a fixed-bounds Normalize transforms identically in train and eval mode
    try:
        return tf(X)
    finally:
        tf.train(was_training)


def exact_nll(model: SingleTaskGP, jitter: float = 1e-6, max_tries: int = 4, X_t: Tensor | None = None) -> Tensor:
    """Negative log marginal likelihood per point: GPyTorch's exact MLL, negated, for our models.

    Valid for the models built here (ARD Matern ScaleKernel, constant mean, Gaussian likelihood
    with constant or fixed per-point noise). Hyperparameter priors enter as GPyTorch's MLL adds them:
    ``-(log p(y) + sum log prior) / n``, i.e. the MAP objective.
    """
    X_t = train_inputs_transformed(model) if X_t is None else X_t
    y = model.train_targets
    n = y.shape[-1]
    kernel = model.covar_module
    ls = kernel.base_kernel.lengthscale.reshape(-1)
    noise = model.likelihood.noise.reshape(-1)
    const = model.mean_module.constant.reshape(())
    nll = _MaternGPNLL.apply(
        ls, kernel.outputscale.reshape(()), noise, const, X_t, y, kernel.base_kernel.nu, jitter, max_tries
    )
    for _, module, prior, closure, _ in model.named_priors():
        nll = nll - prior.log_prob(closure(module)).sum()
    return nll / n


def exact_gp_settings() -> Any:
    """GPyTorch switches to CG / Lanczos approximations above 800 points; the MDE stays exact."""
    return gpytorch.settings.max_cholesky_size(1_000_000)


# -- models ----------------------------------------------------------------------------------------
class MDEGP(SingleTaskGP):
    """SingleTaskGP on z-scored deviations whose ``posterior`` knows the heteroscedastic noise.

    ``posterior(X)`` is in LABEL units (a ``Standardize`` outcome transform maps back) and is the
    posterior of the latent deviation function only. ``posterior(X, observation_noise=True)``
    adds the noise at ``X``: the noise GP's out-of-sample prediction ``exp(mean log noise)`` for
    the heteroscedastic model, the learned constant noise for the homoscedastic one.
    """

    noise_model: SingleTaskGP | None

    def __init__(self, *args: Any, noise_floor: float = 1e-4, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.noise_model = None
        self.noise_floor = float(noise_floor)
        #: raw inputs (n x d) -> log noise variance (label units); set by the MDE to its cached noise mean
        #: (:class:`mde.kernel_cache.KernelCache`), so that ``posterior`` and ``predict`` read one noise
        self.log_noise_fn: Any = None

    def set_noise_model(self, noise_model: SingleTaskGP | None) -> None:
        """Attach a fitted noise GP (frozen: it must not move when this GP is refitted)."""
        if noise_model is not None:
            noise_model.requires_grad_(False)
            noise_model.eval()
            tf = noise_model.outcome_transform
            self.log_noise_max = float(noise_model.train_targets.max() * tf.stdvs.reshape(()) + tf.means.reshape(()))
        self.noise_model = noise_model

    def noise_variance(self, X: Tensor) -> Tensor:
        """Heteroscedastic noise variance at raw inputs ``X`` (``... x q x d``), z-scored units.

        The noise GP models the log noise variance in label units (so that it does not depend on
        this GP's z-scoring); here it is mapped to z-scored units and floored.
        """
        if self.noise_model is None:
            raise RuntimeError("noise_variance needs a heteroscedastic model")
        if self.log_noise_fn is not None:
            log_noise = self.log_noise_fn(X.reshape(-1, X.shape[-1])).reshape(X.shape[:-1]).to(X.dtype)
        else:
            with exact_gp_settings():
                log_noise = self.noise_model.posterior(X).mean.squeeze(-1)
        # never above the largest noise seen in the data: far from the data the log-noise GP can
        # extrapolate above every training value, which made every novel transition "uncertain"
        log_noise = log_noise.clamp_max(self.log_noise_max)
        var_z = log_noise.exp() / self.outcome_transform.stdvs.reshape(()) ** 2
        return var_z.clamp_min(self.noise_floor)

    def posterior(  # type: ignore[override]
        self,
        X: Tensor,
        output_indices: list[int] | None = None,
        observation_noise: bool | Tensor = False,
        posterior_transform: Any = None,
        **kwargs: Any,
    ):
        if observation_noise is True and self.noise_model is not None:
            observation_noise = self.noise_variance(X).unsqueeze(-1)
        with exact_gp_settings():
            return super().posterior(
                X,
                output_indices=output_indices,
                observation_noise=observation_noise,
                posterior_transform=posterior_transform,
                **kwargs,
            )


class DiagonalModel(Model):
    """A one-output BoTorch model whose posterior has independent rows (diagonal covariance).

    Subclasses give per-row mean and variance (:meth:`mean_var`); this class shapes them into a
    posterior over ``batch x q``.
    """

    @property
    def num_outputs(self) -> int:
        return 1

    @property
    def batch_shape(self) -> torch.Size:
        return torch.Size()

    def mean_var(self, X: Tensor, observation_noise: bool | Tensor) -> tuple[Tensor, Tensor]:  # pragma: no cover
        """Mean and variance at each row of ``X`` (... x d) -> (...), (...)."""
        raise NotImplementedError

    def posterior(  # type: ignore[override]
        self,
        X: Tensor,
        output_indices: list[int] | None = None,
        observation_noise: bool | Tensor = False,
        posterior_transform: Any = None,
        **kwargs: Any,
    ) -> GPyTorchPosterior:
        mean, var = self.mean_var(X, observation_noise)
        post = GPyTorchPosterior(MultivariateNormal(mean, DiagLinearOperator(var)))
        return post if posterior_transform is None else posterior_transform(post)


class MarginalModel(DiagonalModel):
    """BoTorch view of an MDE's per-row marginals: its ``mean_var(X, observation_noise)`` (label units, the
    fit's cached factorisation, no autograd), which is what the trajectory acquisitions read.

    GPyTorch's own posterior refactorises the kernel with a smaller jitter cap than the fit accepts and can
    fail on a fit the MDE uses; this view gives the acquisitions the planner's numbers. A tensor
    ``observation_noise`` (BoTorch's "add this noise variance") is added to the latent variance.
    """

    def __init__(self, mde: Any) -> None:
        super().__init__()
        self._mde = mde

    def mean_var(self, X: Tensor, observation_noise: bool | Tensor) -> tuple[Tensor, Tensor]:
        flat = X.detach().reshape(-1, X.shape[-1])
        extra = isinstance(observation_noise, Tensor)
        mean, var = self._mde.mean_var(flat, observation_noise=False if extra else bool(observation_noise))
        mean, var = mean.reshape(X.shape[:-1]).to(X.dtype), var.reshape(X.shape[:-1]).to(X.dtype)
        if extra:
            var = var + observation_noise.to(var).reshape(var.shape)
        return mean, var

    def covariance(self, Xa: Tensor, Xb: Tensor) -> Tensor:
        """The MDE's latent posterior covariance between two sets of rows (label units): the marginals above
        are its diagonal. For look-ahead acquisitions; the planner and the per-step acquisitions never need it."""
        return self._mde.covariance(Xa.detach(), Xb.detach()).to(Xa.dtype)


class PriorMDEModel(DiagonalModel):
    """BoTorch model of the MDE before any data: mean 0, std ``prior_std`` (label units), iid.

    Lets acquisition functions run before the first fit. There is no noise model yet, so
    ``observation_noise`` changes nothing: all of the prior variance counts as latent.
    """

    def __init__(self, prior_std: float = 1.0, dtype: torch.dtype = DTYPE) -> None:
        super().__init__()
        self.prior_std = float(prior_std)
        self._dtype = dtype

    def mean_var(self, X: Tensor, observation_noise: bool | Tensor) -> tuple[Tensor, Tensor]:
        shape = X.shape[:-1]
        dtype = X.dtype if X.is_floating_point() else self._dtype
        mean = torch.zeros(shape, dtype=dtype, device=X.device)
        return mean, torch.full(shape, self.prior_std**2, dtype=dtype, device=X.device)

    def covariance(self, Xa: Tensor, Xb: Tensor) -> Tensor:
        return iid_covariance(Xa, Xb, self.prior_std).to(Xa.dtype if Xa.is_floating_point() else self._dtype)


def iid_covariance(Xa: Tensor, Xb: Tensor, std: float) -> Tensor:
    """``a x b`` covariance (float64) of an iid prior with this std: identical rows covary with ``std^2``, others
    not at all (the MDE before any data)."""
    return (Xa.unsqueeze(-2) == Xb.unsqueeze(-3)).all(dim=-1).to(torch.float64) * std**2


def data_bounds(X: Tensor) -> Tensor:
    """``2 x d`` bounds of the data for ``Normalize``; flat dimensions get a unit range."""
    lo = X.min(dim=0).values
    hi = X.max(dim=0).values
    hi = torch.where(hi - lo > 1e-8 * (1.0 + lo.abs()), hi, lo + 1.0)
    return torch.stack([lo, hi])


def _kernel(nu: float, d: int, X_t: Tensor, lengthscale_max: float | None = None, priors: str = "none") -> ScaleKernel:
    """ARD Matern in a ScaleKernel, lengthscales initialised at twice each input's spread.

    Inputs are unscaled by default, so GPyTorch's fixed initial lengthscale (0.69) could be orders
    of magnitude off for some features; a data-based start keeps L-BFGS out of flat regions.
    ``lengthscale_max`` (in standard deviations of each input over ``X_t``): an upper bound on every
    lengthscale (GPyTorch ``Interval``; a constant input's std counts as 1), starting at half the
    bound. Why: on simulator data the log-noise GP's marginal likelihood prefers a lengthscale in
    the cup's height longer than the whole move range, which smears the noise of pours that hit a
    leaf over the safe pours 3 cm below.
    ``priors="gamma"``: BoTorch's SingleTaskGP default priors before 0.12, the library the paper
    used (``botorch.models.utils.gpytorch_modules.get_matern_kernel_with_gamma_prior``):
    lengthscale Gamma(3, 6) in the kernel's input units (mode 1/3), outputscale Gamma(2, 0.15).
    ``priors="lognormal"``: BoTorch's default since 0.12, the dimension-scaled prior of Hvarfner et al.
    (2024; ``get_covar_module_with_dim_scaled_prior``): lengthscale / range of its input over ``X_t``
    ~ LogNormal(sqrt 2 + log(d) / 2, sqrt 3), i.e. BoTorch's unit-cube prior carried to the kernel's
    input units (a flat input's range counts as 1); the outputscale stays free.
    """
    _check_priors(priors)
    if X_t.shape[0] > 1:
        raw_std = X_t.std(dim=0)
    else:
        raw_std = torch.ones(d, dtype=DTYPE)
    varies = raw_std > 1e-6
    std = torch.where(varies, raw_std, torch.ones_like(raw_std)).to(DTYPE)
    gamma = priors == "gamma"
    ls_prior = GammaPrior(3.0, 6.0) if gamma else None
    if priors == "lognormal":
        span = data_bounds(X_t.to(DTYPE)).diff(dim=0).reshape(d)
        ls_prior = LogNormalPrior(
            loc=math.sqrt(2.0) + 0.5 * math.log(d) + span.log(), scale=torch.full((d,), math.sqrt(3.0), dtype=DTYPE)
        )
    if lengthscale_max is None:
        base = MaternKernel(nu=nu, ard_num_dims=d, lengthscale_prior=ls_prior)
        start = torch.where(varies, 2.0 * std, std)  # a constant input starts at 1
    else:
        hi = lengthscale_max * std
        base = MaternKernel(
            nu=nu, ard_num_dims=d, lengthscale_prior=ls_prior, lengthscale_constraint=Interval(1e-4 * std, hi)
        )
        start = 0.5 * hi
    k = ScaleKernel(base, outputscale_prior=GammaPrior(2.0, 0.15) if gamma else None).to(DTYPE)
    base.lengthscale = start.reshape(1, d)
    k.outputscale = torch.tensor(1.0, dtype=DTYPE)
    return k


def _check_priors(priors: str) -> None:
    if priors not in ALLOWED_PRIORS:
        raise ValueError(f"hyperparameter_priors must be one of {ALLOWED_PRIORS}, got {priors!r}")


def _likelihood(noise_floor: float, start: float, priors: str) -> GaussianLikelihood:
    """Learned constant noise; ``priors="gamma"`` adds BoTorch's old default Gamma(1.1, 0.05) noise prior,
    ``"lognormal"`` its current LogNormal(-4, 1) (``get_gaussian_likelihood_with_lognormal_prior``), both on the
    noise variance of z-scored labels."""
    noise_prior = None
    if priors == "gamma":
        noise_prior = GammaPrior(1.1, 0.05)
    elif priors == "lognormal":
        noise_prior = LogNormalPrior(torch.tensor(-4.0, dtype=DTYPE), torch.tensor(1.0, dtype=DTYPE))
    likelihood = GaussianLikelihood(noise_prior=noise_prior, noise_constraint=GreaterThan(noise_floor)).to(DTYPE)
    likelihood.noise = torch.tensor(start, dtype=DTYPE)
    return likelihood


def _input_transform(bounds: Tensor | None) -> Normalize | None:
    if bounds is None:
        return None
    return Normalize(d=bounds.shape[-1], bounds=bounds)


def _transformed(X: Tensor, bounds: Tensor | None) -> Tensor:
    if bounds is None:
        return X
    lo, hi = bounds
    return (X - lo) / (hi - lo)


def build_mean_gp(
    X: Tensor,
    y: Tensor,
    *,
    nu: float,
    bounds: Tensor | None,
    noise_floor: float,
    train_Yvar: Tensor | None = None,
    lengthscale_max: float | None = None,
    latent_std_min: float | None = None,
    latent_std_max: float | None = None,
    priors: str = "none",
) -> MDEGP:
    """Mean GP on deviations: z-scored labels, prior mean fixed at zero deviation.

    ``train_Yvar`` (label units) gives a fixed per-point noise (heteroscedastic step); without it
    the noise is one learned constant (homoscedastic). ``latent_std_min`` (label units) bounds the
    outputscale below by ``(latent_std_min / label std)^2``, so that the latent std far from the
    data is at least that whatever the labels' spread (the bound is saved with the model's state);
    ``latent_std_max`` bounds it above in the same way (``(latent_std_max / label std)^2``).
    ``priors``: hyperparameter priors, "none", "gamma" or "lognormal" (see :func:`_kernel`).
    """
    Y = y.reshape(-1, 1)
    likelihood = None
    if train_Yvar is None:
        likelihood = _likelihood(noise_floor, max(0.1, 2 * noise_floor), priors)
    with warnings.catch_warnings():
        # Unscaled inputs are the paper's choice; BoTorch warns about them.
        warnings.simplefilter("ignore", InputDataWarning)
        model = MDEGP(
            X,
            Y,
            train_Yvar=None if train_Yvar is None else train_Yvar.reshape(-1, 1),
            likelihood=likelihood,
            covar_module=_kernel(nu, X.shape[-1], _transformed(X, bounds), lengthscale_max, priors),
            mean_module=ConstantMean().to(DTYPE),
            outcome_transform=Standardize(m=1),
            input_transform=_input_transform(bounds),
            noise_floor=noise_floor,
        )
    # Prior mean = zero deviation in label units, i.e. -mu_z / sigma_z in z-scored units; fixed.
    tf = model.outcome_transform
    model.mean_module.constant = (-tf.means / tf.stdvs).reshape(())
    model.mean_module.raw_constant.requires_grad_(False)
    if latent_std_min is not None or latent_std_max is not None:
        lower = 1e-6 if latent_std_min is None else (latent_std_min / float(tf.stdvs)) ** 2
        kernel = model.covar_module
        if latent_std_max is None:
            kernel.register_constraint("raw_outputscale", GreaterThan(lower))
            kernel.outputscale = torch.tensor(max(1.0, 2.0 * lower), dtype=DTYPE)
        else:
            upper = (latent_std_max / float(tf.stdvs)) ** 2
            kernel.register_constraint("raw_outputscale", Interval(lower, upper))
            kernel.outputscale = torch.tensor(min(max(1.0, 2.0 * lower), 0.5 * (lower + upper)), dtype=DTYPE)
    return model


def build_noise_gp(
    X: Tensor,
    log_noise: Tensor,
    *,
    nu: float,
    bounds: Tensor | None,
    lengthscale_max: float | None = None,
    priors: str = "none",
) -> SingleTaskGP:
    """GP on the log of the empirical noise variance (z-scored label units), learned mean."""
    likelihood = _likelihood(1e-4, 0.5, priors)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InputDataWarning)
        model = SingleTaskGP(
            X,
            log_noise.reshape(-1, 1),
            likelihood=likelihood,
            covar_module=_kernel(nu, X.shape[-1], _transformed(X, bounds), lengthscale_max, priors),
            mean_module=ConstantMean().to(DTYPE),
            outcome_transform=Standardize(m=1),
            input_transform=_input_transform(bounds),
        )
    return model


def _accept_abnormal_line_search(w: warnings.WarningMessage) -> bool:
    """L-BFGS-B's "ABNORMAL" line-search stop happens at (or next to) an optimum when the last steps
    no longer decrease the loss in float64; the iterate it returns is a usable fit. BoTorch's
    default handler counts it as a failed attempt, and after its retries the whole fit failed
    (seen on simulator data of 60 transitions), leaving the MDE at its prior."""
    if issubclass(w.category, OptimizationWarning) and "ABNORMAL" in str(w.message):
        return True
    return DEFAULT_WARNING_HANDLER(w)


def fit_gp(model: SingleTaskGP, *, maxiter: int, jitter: float, max_tries: int) -> float:
    """Fit hyperparameters with BoTorch's ``fit_gpytorch_mll``; returns the log ML per point."""
    mll = ExactMarginalLogLikelihood(model.likelihood, model)
    mll.train()
    X_t = train_inputs_transformed(model).detach()
    params, _ = get_parameters_and_bounds(mll)
    params = {name: p for name, p in params.items() if p.requires_grad}
    # Box on the raw (softplus) parameters: wide enough never to bind at a sensible optimum, but
    # keeps L-BFGS-B's first trial steps from over/underflowing the kernel.
    bounds = {name: (RAW_LOWER, RAW_UPPER) for name in params}
    closure = ForwardBackwardClosure(forward=lambda: exact_nll(model, jitter, max_tries, X_t=X_t), parameters=params)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InputDataWarning)
        fit_gpytorch_mll(
            mll,
            closure=closure,
            optimizer_kwargs={"options": {"maxiter": maxiter}, "bounds": bounds},
            max_attempts=2,
            warning_handler=_accept_abnormal_line_search,
        )
    model.eval()
    with torch.no_grad():
        return -float(exact_nll(model, jitter, max_tries, X_t=X_t))


def log_ml(model: SingleTaskGP, *, jitter: float = 1e-6, max_tries: int = 4) -> float:
    """Log marginal likelihood per point of a built model (no fitting)."""
    with torch.no_grad():
        return -float(exact_nll(model, jitter, max_tries))
