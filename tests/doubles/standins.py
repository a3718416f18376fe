"""STAND-INS for the learned dynamics model and the MDE (tests and ``benchmarks.planner`` only).

The real dynamics model (trained on source-world simulator data, :mod:`dynamics`) and the real GP
MDE (:class:`mde.GPMDE`) are slow to make; the planner's tests exercise it with these substitutes,
which follow the same interfaces:

* :class:`AnalyticPouringModel` -- closed-form pouring physics (move sets x, y; pour tips water
  out beyond a fill-dependent critical angle, at a rate set by the hold time, and it lands in
  the target cup when the pouring lip is over the target cup's mouth).
* :class:`StandInMLPDynamics` -- the analytic model plus a small residual from an 8-128-128-5
  MLP, so that planning timings include a network of realistic size.
* :class:`StandInGPMDE` -- an exact GP regressor (ARD Matern-5/2, fixed heuristic hyper-
  parameters, z-scored labels with the prior mean at zero deviation) with the MDE's
  ``predict(X) -> (mean, std)`` signature. Not heteroscedastic and not fitted by marginal
  likelihood; its cost per prediction (O(n^2) variance) is that of an exact GP on n points.
* :func:`synthetic_deviation_dataset` -- labelled (X, d) pairs from a made-up deviation field
  with a "plant" region where the model is wrong.
* :class:`ToyPointRobot` / :class:`ToyBoxMDE` -- a 2-D point robot embedded in the 5-D state
  with a known forbidden box, for correctness tests of the precondition.

None of the numbers here are measured from the simulator; do not report them as results.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor, nn

from planner.config import PlannerConfig
from planner.interfaces import FEATURE_DIM, SKILL_MOVE, SKILL_POUR, STATE_DIM, features
from planner.sampling import ActionSampler
from task.threads import torch_threads

# -- analytic pouring stand-in ------------------------------------------------------------------
TARGET_CUP_X = 0.15  # centre of the target cup's mouth (m)
TARGET_CUP_HALF_WIDTH = 0.06
CUP_HALF_WIDTH = 0.03  # controlled cup
CUP_HEIGHT = 0.08


class AnalyticPouringModel(nn.Module):
    """Closed-form stand-in dynamics, batched in torch (see the module docstring).

    ``move(x, y)``: pose becomes (x, y, 0), water unchanged.
    ``pour(theta, hold)``: the cup tips about its floor centre towards the target cup. Water above
    the lip level leaves: the cup keeps at most ``capacity(theta) = 1 - (a/h) tan(theta)`` of its
    volume (0 beyond ~1.21 rad). Of the excess, ``1 - exp(-(hold + 0.2) / 0.3)`` flows out. The
    stream falls from the pouring lip; the fraction landing between the target cup's walls is a
    smooth window in the lip's x position. The rest is spilled. The cup returns upright.
    """

    def __init__(
        self,
        target_x: float = TARGET_CUP_X,
        target_half_width: float = TARGET_CUP_HALF_WIDTH,
        cup_half_width: float = CUP_HALF_WIDTH,
        cup_height: float = CUP_HEIGHT,
        edge_softness: float = 0.004,
    ) -> None:
        super().__init__()
        self.target_x = target_x
        self.target_half_width = target_half_width
        self.a = cup_half_width
        self.h = cup_height
        self.edge = edge_softness

    def forward(self, states: Tensor, actions: Tensor) -> Tensor:
        return self.predict(states, actions)

    def predict(self, states: Tensor, actions: Tensor) -> Tensor:
        s, a = states, actions.to(states.dtype)
        x, y, vc, vt = s[:, 0], s[:, 1], s[:, 3], s[:, 4]
        is_move = a[:, 0].round() == SKILL_MOVE
        # pour
        theta = a[:, 1].clamp(0.0, math.pi)
        hold = a[:, 2].clamp_min(0.0)
        tan = torch.tan(theta.clamp(max=1.5))
        capacity = torch.where(theta < 1.5, (1.0 - (self.a / self.h) * tan).clamp(0.0, 1.0), torch.zeros_like(theta))
        excess = (vc - capacity).clamp_min(0.0)
        out = excess * (1.0 - torch.exp(-(hold + 0.2) / 0.3))
        direction = torch.where(x >= self.target_x, -1.0, 1.0).to(s.dtype)
        lip_x = x + direction * (self.a * torch.cos(theta) + self.h * torch.sin(theta).clamp_min(0.0))
        lo = self.target_x - self.target_half_width
        hi = self.target_x + self.target_half_width
        inside = torch.sigmoid((lip_x - lo) / self.edge) * torch.sigmoid((hi - lip_x) / self.edge)
        nxt = s.clone()
        nxt[:, 2] = 0.0
        pour_vc = vc - out
        pour_vt = vt + out * inside
        nxt[:, 3] = torch.where(is_move, vc, pour_vc)
        nxt[:, 4] = torch.where(is_move, vt, pour_vt)
        nxt[:, 0] = torch.where(is_move, a[:, 1], x)
        nxt[:, 1] = torch.where(is_move, a[:, 2], y)
        return nxt


class StandInMLPDynamics(nn.Module):
    """Analytic model + ``residual_scale`` * MLP(concat(s, a)) with an 8-128-128-5 MLP.

    The MLP is randomly initialised from ``seed`` (it is not trained): it only gives the planner
    the compute cost of a realistically sized learned model and a small, smooth model error.
    """

    def __init__(
        self, hidden: int = 128, residual_scale: float = 1e-3, seed: int = 0, dtype: torch.dtype = torch.float32
    ) -> None:
        super().__init__()
        gen = torch.Generator().manual_seed(seed)
        self.analytic = AnalyticPouringModel()
        self.net = nn.Sequential(
            nn.Linear(FEATURE_DIM, hidden),
            nn.Tanh(),
            nn.Linear(hidden, hidden),
            nn.Tanh(),
            nn.Linear(hidden, STATE_DIM),
        )
        with torch.no_grad():
            for p in self.net.parameters():
                p.copy_(torch.randn(p.shape, generator=gen) * (1.0 / math.sqrt(p.shape[-1])))
        self.residual_scale = residual_scale
        self.to(dtype)

    def predict(self, states: Tensor, actions: Tensor) -> Tensor:
        base = self.analytic.predict(states, actions)
        res = self.net(torch.cat([states, actions.to(states.dtype)], dim=-1))
        res = res * torch.tensor([1.0, 1.0, 0.0, 1.0, 1.0], dtype=res.dtype)  # keep theta = 0
        return base + self.residual_scale * res


# -- GP stand-in for the MDE --------------------------------------------------------------------
class StandInGPMDE:
    """Exact GP regression of deviations with the MDE interface (stand-in, see module docstring).

    Labels are z-scored; the prior mean in z-space is ``-mu_z / sigma_z`` so that far from data
    the prediction reverts to zero deviation, as in the paper. Inputs are unscaled. Kernel:
    ``outputscale * Matern52`` with ARD lengthscales. With ``optimize=True`` the lengthscales,
    outputscale and noise maximise the marginal likelihood on a random subset of at most
    ``fit_subset`` points (Adam, ``fit_iters`` steps) -- cheap, and close enough for a stand-in;
    the posterior is then conditioned on all points.
    """

    def __init__(
        self,
        noise: float = 1e-2,
        lengthscale_factor: float = 0.5,
        outputscale: float = 1.0,
        optimize: bool = True,
        fit_iters: int = 100,
        fit_subset: int = 300,
        seed: int = 0,
        dtype: torch.dtype = torch.float64,
    ) -> None:
        self.noise0 = noise
        self.lengthscale_factor = lengthscale_factor
        self.outputscale0 = outputscale
        self.optimize = optimize
        self.fit_iters = fit_iters
        self.fit_subset = fit_subset
        self.seed = seed
        self.dtype = dtype
        self._fitted = False

    def fit(self, X, y) -> "StandInGPMDE":
        # small dense problems: one torch thread is faster and immune to busy-machine stalls
        with torch_threads(1):
            return self._fit(X, y)

    def _fit(self, X, y) -> "StandInGPMDE":
        X = torch.as_tensor(X, dtype=self.dtype)
        y = torch.as_tensor(y, dtype=self.dtype).reshape(-1)
        if X.ndim != 2 or X.shape[1] != FEATURE_DIM or len(X) != len(y) or len(y) < 2:
            raise ValueError(f"need X [n, {FEATURE_DIM}] and y [n] with n >= 2; got {tuple(X.shape)}, {tuple(y.shape)}")
        self.mu_z = y.mean()
        self.sd_z = y.std().clamp_min(1e-6)
        z = (y - self.mu_z) / self.sd_z
        self.prior_z = -self.mu_z / self.sd_z
        spread = X.std(0)
        ls = self.lengthscale_factor * torch.where(spread > 1e-9, spread, torch.ones_like(spread))
        log_ls = ls.log()
        log_os = torch.tensor(math.log(self.outputscale0), dtype=self.dtype)
        log_noise = torch.tensor(math.log(self.noise0), dtype=self.dtype)
        if self.optimize:
            gen = torch.Generator().manual_seed(self.seed)
            idx = torch.randperm(len(X), generator=gen)[: self.fit_subset]
            log_ls, log_os, log_noise = self._ml2(X[idx], z[idx] - self.prior_z, log_ls, log_os, log_noise)
        self.ls, self.outputscale, self.noise = log_ls.exp(), log_os.exp(), log_noise.exp()
        self.Xs = X / self.ls
        K = self.outputscale * self._k(self.Xs, self.Xs) + self.noise * torch.eye(len(X), dtype=self.dtype)
        self.L = torch.linalg.cholesky(K)
        self.alpha = torch.cholesky_solve((z - self.prior_z).unsqueeze(1), self.L).squeeze(1)
        self._fitted = True
        return self

    def _ml2(self, X: Tensor, r: Tensor, log_ls: Tensor, log_os: Tensor, log_noise: Tensor):
        params = [p.clone().requires_grad_(True) for p in (log_ls, log_os, log_noise)]
        opt = torch.optim.Adam(params, lr=0.05)
        eye = torch.eye(len(X), dtype=self.dtype)
        for _ in range(self.fit_iters):
            opt.zero_grad()
            ls, os_, nz = params[0].exp(), params[1].exp(), params[2].exp().clamp_min(1e-6)
            K = os_ * self._k(X / ls, X / ls) + nz * eye
            L = torch.linalg.cholesky(K)
            a = torch.cholesky_solve(r.unsqueeze(1), L).squeeze(1)
            nll = 0.5 * (r @ a) + torch.log(torch.diagonal(L)).sum()
            nll.backward()
            opt.step()
        return tuple(p.detach() for p in params)

    @staticmethod
    def _k(A: Tensor, B: Tensor) -> Tensor:
        r = torch.cdist(A, B).clamp_min(1e-12) * math.sqrt(5.0)
        return (1.0 + r + r * r / 3.0) * torch.exp(-r)

    def predict(self, X: Tensor) -> tuple[Tensor, Tensor]:
        if not self._fitted:
            raise RuntimeError("StandInGPMDE.predict called before fit")
        with torch.no_grad():
            Xs = torch.as_tensor(X, dtype=self.dtype) / self.ls
            Ks = self.outputscale * self._k(Xs, self.Xs)  # [m, n]
            mean_z = self.prior_z + Ks @ self.alpha
            v = torch.linalg.solve_triangular(self.L, Ks.T, upper=False)
            var_z = (self.outputscale - (v * v).sum(0)).clamp_min(1e-10)
            return mean_z * self.sd_z + self.mu_z, var_z.sqrt() * self.sd_z


def plant_deviation(X: np.ndarray) -> np.ndarray:
    """Made-up true deviation field (stand-in for sim data): the model is wrong near a "plant".

    Pours from above the canopy (cup over x in [0.17, 0.32] higher than y = 0.14) deviate
    strongly (water hits leaves); moves whose end point is inside the plant's stem/leaves box
    x in [0.20, 0.30], y in [0.10, 0.35] get stuck; everything else deviates a little.
    """
    X = np.atleast_2d(X)
    x, y = X[:, 0], X[:, 1]
    skill, p1, p2 = np.rint(X[:, 5]), X[:, 6], X[:, 7]
    d = 0.01 + 0.01 * X[:, 3]
    over_canopy = (skill == SKILL_POUR) & (x > 0.17) & (x < 0.32) & (y > 0.14) & (p1 > 0.6)
    d = np.where(over_canopy, 0.25, d)
    stuck = (skill == SKILL_MOVE) & (p1 > 0.20) & (p1 < 0.30) & (p2 > 0.10)
    d = np.where(stuck, 0.15, d)
    return d


#: start region (m) of the synthetic rollouts: upright full cups in the analytic stand-in's own world (the
#: planner's former default problem region; the task's problems are the world's, task.problems)
SYNTHETIC_STARTS = {"x": (0.3, 0.55), "y": (0.05, 0.3)}


def synthetic_deviation_dataset(
    n: int, rng: np.random.Generator, config: PlannerConfig | None = None, noise: float = 0.005
) -> tuple[np.ndarray, np.ndarray]:
    """(X [n, 8], d [n]) from random 6-action rollouts of the analytic model from :data:`SYNTHETIC_STARTS`.

    Rollouts use the planner's :class:`ActionSampler`, so the features cover the states the
    planner visits; labels are :func:`plant_deviation` plus Gaussian noise, clipped at 0.
    """
    config = config or PlannerConfig()
    sampler = ActionSampler(config)
    model = AnalyticPouringModel()
    n_roll = math.ceil(n / config.max_actions)
    s = np.zeros((n_roll, STATE_DIM))
    s[:, 0] = rng.uniform(*SYNTHETIC_STARTS["x"], n_roll)
    s[:, 1] = rng.uniform(*SYNTHETIC_STARTS["y"], n_roll)
    s[:, 3] = 1.0
    feats = []
    with torch.no_grad():
        for _ in range(config.max_actions):
            a = sampler.sample(n_roll, rng)
            feats.append(features(s, a))
            s = model.predict(torch.as_tensor(s), torch.as_tensor(a)).numpy()
            s = np.clip(s, config.state_low, config.state_high)
    X = np.concatenate(feats)[:n]
    d = np.clip(plant_deviation(X) + noise * rng.standard_normal(len(X)), 0.0, None)
    return X, d


def fitted_standin_mde(n: int = 1200, seed: int = 0, config: PlannerConfig | None = None) -> StandInGPMDE:
    """A :class:`StandInGPMDE` fitted on ``n`` synthetic points (what the bench uses)."""
    X, d = synthetic_deviation_dataset(n, np.random.default_rng(seed), config)
    return StandInGPMDE().fit(X, d)


# -- toy point robot ------------------------------------------------------------------------------
class ToyPointRobot:
    """2-D point robot in the 5-D state, for tests with a known answer.

    ``move(x, y)`` goes straight towards (x, y) but at most ``max_step`` far. ``pour(theta, hold)``
    moves ``v_ctrl * theta / 2.4`` of the water: into the target cup when the robot is left of
    ``pour_zone_x``, onto the floor (spill) otherwise. ``hold`` is ignored.
    """

    def __init__(self, max_step: float = 0.2, pour_zone_x: float = 0.15) -> None:
        self.max_step = max_step
        self.pour_zone_x = pour_zone_x
        self.calls = 0
        self.rows = 0

    def end_points(self, states: Tensor, actions: Tensor) -> Tensor:
        """Where a move ends (for pours: where the robot already is)."""
        d = actions[:, 1:3] - states[:, :2]
        n = torch.linalg.norm(d, dim=1, keepdim=True)
        scale = torch.where(n > self.max_step, self.max_step / n.clamp_min(1e-12), torch.ones_like(n))
        end = states[:, :2] + d * scale
        is_move = actions[:, 0].round() == SKILL_MOVE
        return torch.where(is_move.unsqueeze(1), end, states[:, :2])

    def predict(self, states: Tensor, actions: Tensor) -> Tensor:
        self.calls += 1
        self.rows += len(states)
        actions = actions.to(states.dtype)
        nxt = states.clone()
        nxt[:, :2] = self.end_points(states, actions)
        nxt[:, 2] = 0.0
        is_pour = actions[:, 0].round() == SKILL_POUR
        out = states[:, 3] * (actions[:, 1] / 2.4).clamp(0.0, 1.0)
        into = states[:, 0] < self.pour_zone_x
        nxt[:, 3] = torch.where(is_pour, states[:, 3] - out, states[:, 3])
        nxt[:, 4] = torch.where(is_pour & into, states[:, 4] + out, states[:, 4])
        return nxt


class ToyBoxMDE:
    """MDE stand-in for :class:`ToyPointRobot`: huge deviation if a move's path enters a box.

    The path is checked at ``n_checks`` points along the straight segment. Outside the box the
    deviation is ``base`` with std ``std``; inside it is ``high`` with the same std.
    """

    def __init__(
        self,
        robot: ToyPointRobot,
        box: tuple[float, float, float, float] = (0.2, 0.3, 0.0, 0.25),
        base: float = 0.01,
        high: float = 1.0,
        std: float = 0.01,
        n_checks: int = 16,
    ) -> None:
        self.robot = robot
        self.box = box
        self.base, self.high, self.std = base, high, std
        self.n_checks = n_checks
        self.calls = 0

    def in_box(self, pts: Tensor) -> Tensor:
        x0, x1, y0, y1 = self.box
        return (pts[..., 0] >= x0) & (pts[..., 0] <= x1) & (pts[..., 1] >= y0) & (pts[..., 1] <= y1)

    def path_hits_box(self, X: Tensor) -> Tensor:
        s, a = X[:, :STATE_DIM], X[:, STATE_DIM:]
        end = self.robot.end_points(s, a)
        t = torch.linspace(0.0, 1.0, self.n_checks, dtype=X.dtype)
        pts = s[:, None, :2] + t[None, :, None] * (end - s[:, :2])[:, None, :]
        return self.in_box(pts).any(dim=1)

    def predict(self, X: Tensor) -> tuple[Tensor, Tensor]:
        self.calls += 1
        hit = self.path_hits_box(X)
        mean = torch.where(hit, torch.full_like(X[:, 0], self.high), torch.full_like(X[:, 0], self.base))
        return mean, torch.full_like(mean, self.std)
