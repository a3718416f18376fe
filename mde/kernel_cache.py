"""Cached closed-form GP prediction for the planner's large batches.

Why not ``model.posterior``: GPyTorch rebuilds lazy tensors and checks on every call, and its
exact variance path forms the full ``b x n`` solve through generic code; the planner asks for
thousands of (s, a) pairs per tree expansion. After ``fit`` the Cholesky factor of the training
covariance and ``alpha = K^-1 (y - m)`` are computed once (float64) and cast to the prediction
dtype; each call is then one kernel block, one triangular solve and a few reductions, done in
chunks so that the ``chunk x n`` block stays in cache. The variances are exact (no LOVE /
low-rank approximation); in float64 (the default, ``MDEConfig.predict_dtype``) they match
``model.posterior`` to rounding (tested). The float32 path (~2x faster) keeps the input map and the
mean's accumulation in float64 and is within ~2e-3 of float64 on synthetic data, but lost all
precision on real simulator features (tests/test_mde_regressions.py), so it is opt-in only.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from .gp import matern_from_dist, safe_cholesky, scaled_dist, train_inputs_transformed

_MATERN_FACTOR = {0.5: 1.0, 1.5: math.sqrt(3.0), 2.5: math.sqrt(5.0)}


class KernelCache:
    """Everything a Matern ScaleKernel GP needs at predict time, in one dtype."""

    def __init__(
        self,
        model,
        nu: float,
        dtype: torch.dtype,
        *,
        jitter: float,
        max_tries: int,
        bounds: Tensor | None,
    ) -> None:
        with torch.no_grad():
            X_t = train_inputs_transformed(model).to(torch.float64)
            n, d = X_t.shape
            ls = model.covar_module.base_kernel.lengthscale.detach().reshape(d).to(torch.float64)
            outputscale = float(model.covar_module.outputscale.detach())
            const = float(model.mean_module.constant.detach())
            noise = model.likelihood.noise.detach().reshape(-1).to(torch.float64).expand(n)
            center = X_t.mean(dim=0)
            Zu = (X_t - center) / ls  # kernel space, before the Matern factor
            # the training kernel from explicit differences, as the fit's objective computes it
            # (mde.gp.scaled_dist): GPyTorch's own distance loses features to cancellation when a
            # lengthscale is ~1e-10 and then this matrix was not positive definite at the fit's optimum
            K = matern_from_dist(scaled_dist(Zu), float(nu)).mul_(outputscale)
            K = K + torch.diag_embed(noise)
            L = safe_cholesky(K, jitter, max_tries)
            y = model.train_targets.detach().to(torch.float64)
            alpha = torch.cholesky_solve((y - const).unsqueeze(-1), L).squeeze(-1)
            # Raw input -> kernel space in one affine map: z = (x - shift) / scale, where the
            # input transform (if any), the centring, the lengthscales and the Matern factor
            # sqrt(2 nu) are folded together, so that the kernel is a function of |z - z'| alone.
            if bounds is None:
                lo, width = torch.zeros(d, dtype=torch.float64), torch.ones(d, dtype=torch.float64)
            else:
                lo, width = bounds[0].to(torch.float64), (bounds[1] - bounds[0]).to(torch.float64)
            c = _MATERN_FACTOR[float(nu)]
            # float64: raw features may carry large offsets that float32 would round away
            self.shift = lo + center * width
            self.scale = width * ls / c
            self.Z = (Zu * c).to(dtype)
            # outputscale s folded in: k = s k0, so K alpha = k0 (s alpha) and
            # ||L^-1 k||^2 = ||(L / s)^-1 k0||^2.
            self.alpha_s = alpha * outputscale  # float64 always: see _mean_from()
            L_s = L / outputscale
            self.L = L_s.to(dtype)
            self.LT = L_s.T.contiguous().to(dtype)
        self.nu = float(nu)
        self.outputscale = outputscale
        self.const = const
        self.dtype = dtype
        self.d = d

    def _z(self, Xq: Tensor) -> Tensor:
        """Raw inputs -> kernel space (cache dtype)."""
        return ((Xq.to(torch.float64) - self.shift) / self.scale).to(self.dtype)

    def cross0(self, Xq: Tensor) -> Tensor:
        """Unit-scale correlations ``k0(Xq, X_train)`` for raw query inputs ``Xq`` (``b x d``)."""
        return self._k0(self._z(Xq), self.Z)

    def covariance(self, Xa: Tensor, Xb: Tensor) -> Tensor:
        """Exact latent posterior covariance ``a x b`` between two sets of raw inputs, the GP's own units,
        float64: ``s k0(a, b) - k(a, X) K^-1 k(X, b)``. What a look-ahead acquisition needs (how much
        observing ``b`` would tell about ``a``); the planner never calls it."""
        Qa, Qb = (
            torch.linalg.solve_triangular(self.L.to(torch.float64), self.cross0(X).to(torch.float64).T, upper=False)
            for X in (Xa, Xb)
        )
        prior = self._k0(self._z(Xa), self._z(Xb)).to(torch.float64).mul_(self.outputscale)
        return prior - Qa.T @ Qb

    def _k0(self, Za: Tensor, Zb: Tensor) -> Tensor:
        """Unit-scale Matern correlations between two sets of kernel-space points."""
        # explicit differences, not |z|^2 + |z'|^2 - 2 z.z': see mde.gp.scaled_dist (as fast here)
        a = torch.cdist(Za, Zb, compute_mode="donot_use_mm_for_euclid_dist")  # = sqrt(2 nu) |x - x'| / lengthscale
        E = a.neg().exp_()
        if self.nu == 0.5:
            return E
        if self.nu == 1.5:
            return a.add_(1.0).mul_(E)
        return a.div(3.0).add_(1.0).mul_(a).add_(1.0).mul_(E)  # (1 + a + a^2/3) e^-a

    def _mean_from(self, K0: Tensor) -> Tensor:
        # The kernel-weighted sum cancels large terms (|alpha| sums to thousands when the noise
        # is small), so it is accumulated in float64 even when the kernel block is float32:
        # a float32 matvec was measured 10x less accurate (2% of the label std at n = 1200).
        if K0.dtype != torch.float64:
            K0 = K0.to(torch.float64)
        return K0 @ self.alpha_s + self.const

    def mean(self, Xq: Tensor) -> Tensor:
        """Posterior mean in the GP's own (transformed-outcome) units, float64."""
        return self._mean_from(self.cross0(Xq))

    def mean_var(self, Xq: Tensor) -> tuple[Tensor, Tensor]:
        """Posterior mean (float64) and exact latent variance (cache dtype), the GP's own units."""
        K0 = self.cross0(Xq)
        mean = self._mean_from(K0)
        if self.dtype == torch.float32:  # (solve orientation: fastest measured per dtype)
            Q = torch.linalg.solve_triangular(self.LT, K0, upper=True, left=False)
            q2 = (Q * Q).sum(dim=1)
        else:
            Q = torch.linalg.solve_triangular(self.L, K0.T, upper=False)
            q2 = (Q * Q).sum(dim=0)
        var = q2.neg_().add_(self.outputscale).clamp_min_(0.0)
        return mean, var


class AffineMean:
    """``scale * cache.mean(X) + shift``: a cached GP's mean mapped back through its outcome transform
    (a picklable callable, for :attr:`mde.gp.MDEGP.log_noise_fn`).

    Why the noise GP's mean goes through the cache and not through ``noise_model.posterior``: with
    lengthscales of ~1e-8 on 0/1 features (seen on simulator data) GPyTorch's distance loses the
    other features' O(1) terms to float64 cancellation; at one query of
    ``tests/data/mde_noise_extrapolation.pt`` its mean was -6.55 where an explicit-difference float64
    computation gives -6.86 and the cache -6.86 (``tests/test_mde_regressions.py``)."""

    def __init__(self, cache: KernelCache, shift: float, scale: float) -> None:
        self.cache, self.shift, self.scale = cache, float(shift), float(scale)

    def __call__(self, X: Tensor) -> Tensor:
        return self.cache.mean(X) * self.scale + self.shift
