"""Trajectory acquisition functions as BoTorch ``AcquisitionFunction`` subclasses.

A candidate trajectory tau = ((s_0, a_0), ..., (s_{T-1}, a_{T-1})) is one q-batch: ``X`` has shape
``batch x T x d`` with d the MDE feature size. Each acquisition turns the MDE posterior of every step
(mean mu_t and std sigma_t of the deviation, in label units) into a per-step score, discounts it by
gamma^t and reduces over steps with a max. BoTorch maximises, so a function whose paper form is
minimised (the paper's alpha) returns -alpha.

To plug in your own: subclass :class:`TrajectoryAcquisition`, implement ``step_score`` and point the
Hydra config at it (``acquisition._target_=my_pkg.MyAcquisition``). The config group
``configs/acquisition/`` holds the built-in ones as ``_partial_: true`` specs (``acquisition=lcb`` ...);
the loop instantiates the partial and completes it with ``model`` and, where the class accepts them,
the method's keyword arguments (``c``) and ``d_max``.
"""

from __future__ import annotations

import hashlib

import torch
from botorch.acquisition import AcquisitionFunction
from botorch.models.model import Model
from botorch.utils.transforms import t_batch_mode_transform
from torch import Tensor


def check_gamma(gamma: float) -> float:
    if not (0.0 < gamma <= 1.0):
        raise ValueError(f"acquisition.gamma = {gamma}: allowed (0, 1]")
    return float(gamma)


class TrajectoryAcquisition(AcquisitionFunction):
    """Base: value(tau) = max_t gamma^t * step_score(mu_t, sigma_t) (or its negative, ``minimise``)."""

    #: True when the paper's form is minimised (forward then returns the negative)
    minimise: bool = False

    def __init__(self, model: Model, gamma: float = 1.0, observation_noise: bool = True) -> None:
        super().__init__(model=model)
        self.gamma = check_gamma(gamma)
        self.observation_noise = observation_noise

    def step_score(self, mean: Tensor, std: Tensor) -> Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def trajectory_score(self, X: Tensor) -> Tensor:
        """The paper-form score of each trajectory in ``X`` (batch x T x d) -> (batch,)."""
        if X.dim() == 2:
            X = X.unsqueeze(0)
        post = self.model.posterior(X, observation_noise=self.observation_noise)
        mean = post.mean.squeeze(-1)
        std = post.variance.clamp_min(0.0).sqrt().squeeze(-1)
        T = X.shape[-2]
        discount = self.gamma ** torch.arange(T, dtype=X.dtype, device=X.device)
        return (discount * self.step_score(mean, std)).amax(dim=-1)

    @t_batch_mode_transform()
    def forward(self, X: Tensor) -> Tensor:
        """``X``: batch x T x d (a 2-D ``T x d`` is one trajectory) -> (batch,), maximised."""
        score = self.trajectory_score(X)
        return -score if self.minimise else score


class DiscountedMaxUCB(TrajectoryAcquisition):
    """The paper's alpha(tau) = max_t gamma^t (mu_t + c sigma_t) (its Eq. 1), minimised, so
    forward = -alpha.

    Note on the sign of c: minimising Eq. 1 with c < 0 *lowers* alpha for uncertain steps (it rewards
    uncertainty), while the paper's text calls c = -0.1 "cautious" and says a higher c gives a higher
    exploration bonus, which is the reading of the LCB form mu - c sigma: :class:`DiscountedMaxLCB`
    (``acquisition=lcb``). This class (the default, as the design brief specifies) uses mu + c sigma.
    """

    minimise = True

    def __init__(self, model: Model, c: float = 0.1, gamma: float = 1.0, observation_noise: bool = True) -> None:
        super().__init__(model, gamma, observation_noise)
        self.c = float(c)

    def step_score(self, mean: Tensor, std: Tensor) -> Tensor:
        return mean + self.c * std


class DiscountedMaxLCB(DiscountedMaxUCB):
    """The LCB reading of the paper's alpha: max_t gamma^t (mu_t - c sigma_t), minimised (a higher c
    rewards uncertain steps more: the paper's naming of c = -0.1 as "cautious")."""

    def step_score(self, mean: Tensor, std: Tensor) -> Tensor:
        return mean - self.c * std


class TrajectoryStraddle(TrajectoryAcquisition):
    """Level-set straddle (Bryan et al. 2005, as used by Wang et al. 2018) around the precondition
    threshold: score_t = kappa sigma_t - |mu_t - d_max|, maximised: a trajectory whose most
    informative step sits near the boundary mu = d_max with large uncertainty is preferred."""

    def __init__(
        self, model: Model, d_max: float = 0.07, kappa: float = 1.96, gamma: float = 1.0, observation_noise: bool = True
    ) -> None:
        super().__init__(model, gamma, observation_noise)
        if d_max <= 0:
            raise ValueError(f"acquisition.d_max = {d_max}: allowed > 0")
        self.d_max = float(d_max)
        self.kappa = float(kappa)

    def step_score(self, mean: Tensor, std: Tensor) -> Tensor:
        return self.kappa * std - (mean - self.d_max).abs()


class TrajectoryVariance(TrajectoryAcquisition):
    """Pure exploration: score_t = sigma_t^2, maximised (the most uncertain step of the trajectory)."""

    def step_score(self, mean: Tensor, std: Tensor) -> Tensor:
        return std**2


class TrajectoryThompson(TrajectoryAcquisition):
    """Thompson sampling over the candidates: score = max_t gamma^t f_t with f one joint draw of the deviation
    posterior over the trajectory's steps, minimised like the paper's alpha (the candidate whose draw is best runs).

    Why: alpha selects on the MDE's point estimate, so it executes the pours the MDE is most wrongly confident about
    (the optimiser's curse; on this world the active methods' MDEs then refuse good partial pours, BENCHMARKS.md,
    admission); a posterior draw picks each candidate about as often as it is probably the best. Each trajectory's
    draw is seeded by its features and ``seed``, so a run is reproducible and a candidate's score does not depend
    on which others it is scored with.
    """

    minimise = True

    def __init__(self, model: Model, seed: int = 0, gamma: float = 1.0, observation_noise: bool = True) -> None:
        super().__init__(model, gamma, observation_noise)
        self.seed = int(seed)

    def _base_samples(self, X: Tensor) -> Tensor:
        """One standard normal per step (batch x T), each trajectory's from a generator seeded by its features."""
        rows = []
        for traj in X:
            digest = hashlib.blake2b(
                traj.detach().cpu().double().numpy().tobytes(),
                digest_size=8,
                key=self.seed.to_bytes(8, "little", signed=True),
            ).digest()
            gen = torch.Generator().manual_seed(int.from_bytes(digest, "little") & (2**63 - 1))
            rows.append(torch.randn(X.shape[-2], generator=gen, dtype=X.dtype))
        return torch.stack(rows).to(X.device)

    def trajectory_score(self, X: Tensor) -> Tensor:
        """The drawn worst step of each trajectory in ``X`` (batch x T x d) -> (batch,)."""
        if X.dim() == 2:
            X = X.unsqueeze(0)
        post = self.model.posterior(X, observation_noise=self.observation_noise)
        draw = post.rsample_from_base_samples(torch.Size([1]), self._base_samples(X).unsqueeze(0))
        draw = draw.reshape(X.shape[:-1])
        discount = self.gamma ** torch.arange(X.shape[-2], dtype=X.dtype, device=X.device)
        return (discount * draw).amax(dim=-1)


class TrajectoryAdmissionGain(TrajectoryAcquisition):
    """Look-ahead for the test planner: the expected number of reference transitions that the test precondition
    ``mu + beta sigma < d_max`` admits once the trajectory's steps are observed, minus the number it admits now;
    maximised.

    Why: the per-step scores rank a trajectory by the MDE's belief about its own steps; the planner at test time
    needs the precondition to admit good transitions of many plans. Observing steps C with noise changes the
    latent posterior at a reference transition r by a normal update of variance v_r = S_rC (S_CC + N_C)^-1 S_Cr
    (exact for a GP: label-independent for the homoscedastic MDE), so its std after is sqrt(var_r - v_r) and its
    mean is N(mu_r, v_r) distributed; P(admitted after) = Phi((d_max - beta std_after - mu_r) / sqrt(v_r)). A
    one-step look-ahead in the spirit of stepwise uncertainty reduction for level sets (Bect et al. 2012) and
    the knowledge gradient, with the test precondition as the quantity of interest.

    ``reference`` (``r x d``): transitions the test planner is likely to need; the loop passes the steps of every
    candidate planned for the current chunk of training problems. None: the trajectory's own steps.
    ``model`` must offer ``covariance(Xa, Xb)`` (the MDE's :class:`mde.gp.MarginalModel` does).
    """

    def __init__(
        self,
        model: Model,
        reference: Tensor | None = None,
        d_max: float = 0.07,
        beta: float = 2.0,
        observation_noise: bool = True,
    ) -> None:
        super().__init__(model, 1.0, observation_noise)
        if d_max <= 0:
            raise ValueError(f"acquisition.d_max = {d_max}: allowed > 0")
        if not callable(getattr(model, "covariance", None)):
            raise TypeError(
                f"{type(self).__name__} needs a model with covariance(Xa, Xb) (e.g. the MDE's "
                f"marginal_model); {type(model).__name__} has none"
            )
        self.d_max, self.beta = float(d_max), float(beta)
        self.reference = None if reference is None else torch.as_tensor(reference, dtype=torch.float64)
        if self.reference is not None and (self.reference.dim() != 2 or not len(self.reference)):
            raise ValueError(
                f"acquisition.reference: expected a non-empty r x d matrix, got shape {tuple(self.reference.shape)}"
            )
        self._now: tuple[Tensor, Tensor] | None = None  # (mean, predictive variance) at the reference

    def _reference_now(self, C: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        if self.reference is None:
            return (C, *self.model.mean_var(C, self.observation_noise))
        if self._now is None:
            self._now = self.model.mean_var(self.reference.to(C), self.observation_noise)
        return (self.reference.to(C), *self._now)

    def gain(self, C: Tensor) -> Tensor:
        """Expected change in the number of admitted reference transitions after observing the steps ``C`` (T x d)."""
        R, mu, var = self._reference_now(C)
        latent_c = self.model.mean_var(C, False)[1]
        noise_c = (self.model.mean_var(C, True)[1] - latent_c).clamp_min(0.0)
        S_rc = self.model.covariance(R, C).to(C)
        S_cc = self.model.covariance(C, C).to(C) + torch.diag_embed(noise_c)
        scale = S_cc.diagonal().mean().clamp_min(1e-30)
        eye = torch.eye(len(C), dtype=C.dtype, device=C.device)
        L, info = torch.linalg.cholesky_ex(S_cc + 1e-9 * scale * eye)
        if int(info):  # a repeated noiseless step: a larger jitter
            L = torch.linalg.cholesky(S_cc + 1e-6 * scale * eye)
        A = torch.linalg.solve_triangular(L, S_rc.T, upper=False)
        v = (A * A).sum(dim=0).clamp(min=0.0)
        v = torch.minimum(v, var)
        sd_after = (var - v).clamp_min(0.0).sqrt()
        slack = self.d_max - self.beta * sd_after - mu
        tiny = v <= 1e-12 * var.clamp_min(1e-30)
        z = slack / v.clamp_min(1e-300).sqrt()
        p_after = torch.where(tiny, (slack > 0).to(C.dtype), torch.special.ndtr(z))
        admitted_now = (mu + self.beta * var.sqrt() < self.d_max).to(C.dtype)
        return (p_after - admitted_now).sum()

    def trajectory_score(self, X: Tensor) -> Tensor:
        """Expected admission gain of each trajectory in ``X`` (batch x T x d) -> (batch,)."""
        if X.dim() == 2:
            X = X.unsqueeze(0)
        return torch.stack([self.gain(traj) for traj in X.detach()])


#: the built-in acquisitions by their name in configs/acquisition/
ACQUISITIONS = {
    "alpha": DiscountedMaxUCB,
    "lcb": DiscountedMaxLCB,
    "straddle": TrajectoryStraddle,
    "variance": TrajectoryVariance,
    "thompson": TrajectoryThompson,
    "admission": TrajectoryAdmissionGain,
}
