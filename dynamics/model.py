"""The learned dynamics model f_hat(s, a): one small MLP per skill with a structured output.

Why this structure (and not a plain "predict s' from (s, a)" network):

* **Pose.** The cup is kinematic: after ``move(x, y)`` it is at the commanded (x, y) unless it got
  stuck on an obstacle; after ``pour`` it is back where it started unless it got stuck mid-tilt.
  Each skill therefore has a *nominal* next pose (move: (p1, p2, theta); pour: the current pose)
  and the network predicts only the residual, in units of that residual's spread in the training
  data. The common case is exact by construction; the network learns where the cup gets stuck.
* **Where the tilting cup goes.** A pour rotates the cup about its pouring lip, so whether it hits
  the tank wall, the floor or the target cup (and then stops tilted, keeping its water) depends on
  the region its outline sweeps. The pour network gets that region's bounding box (computed from
  the cup's own geometry, not from the world's obstacles) as extra inputs, which turns "gets stuck"
  into a threshold on an input instead of a thin curved region of (x, y, theta) space.
* **Water.** Water only leaves the controlled cup: the network outputs three logits whose softmax
  splits the water currently in the controlled cup into (stays, goes to the target cup, spills).
  So v_ctrl' = v_ctrl p_stay, v_tgt' = v_tgt + v_ctrl p_tgt: every prediction has fractions in
  [0, 1] with v_ctrl' + v_tgt' <= 1 (and spill never decreases) for *any* input; input fractions
  outside the simplex are first projected onto it.
* **Normalisation.** Inputs are z-scored per skill with training-set statistics; the pose
  outputs are scaled per skill and component by the residual's RMS in the training data (floored),
  so the network's outputs are O(1). All statistics are buffers, so they travel in the
  checkpoint's ``state_dict``. The training loss is chosen in :class:`dynamics.config.TrainConfig`.

:meth:`LearnedDynamics.predict` is the planner's batched torch API (``planner.interfaces.
DynamicsModel``); :meth:`LearnedDynamics.predict_np` / :meth:`LearnedDynamics.predict_one` are a
numpy path with pre-extracted weights for single transitions, where torch's per-op overhead
dominates.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from torch import Tensor, nn

import safeio

from .config import MODEL_FORMAT_VERSION, DynamicsError, ModelConfig
from .data import atomic_torch_save, load_tagged

CHECKPOINT_FORMAT = "active-mde/dynamics-checkpoint"
STATE_DIM, ACTION_DIM = 5, 3
MOVE, POUR = 0, 1
SKILLS = ("move", "pour")
#: per-skill input features: move sees (s, x_cmd, y_cmd, x_cmd - x, y_cmd - y), pour (s, theta_cmd,
#: hold, bounding box (x_min, x_max, y_min, y_max) of the cup outline swept by the tilt)
FEATURE_DIMS = (9, 11)
OUT_DIM = 6  # 3 pose residuals + 3 water logits (stay, to target, spill)
#: controlled cup (inner width, inner height, wall thickness) in m of the default world; fit()
#: sets the trained world's values, and they travel in the checkpoint
DEFAULT_CUP = (0.07, 0.09, 0.02)
SWEEP_STEPS = 13  # tilt angles sampled for the swept bounding box


def _sweep_geometry(geom: Sequence[float]) -> tuple[float, float, list[float], list[float]]:
    """Lip (pivot) and outer corners of the cup in its own frame (origin: centre of the inner floor)."""
    w, h, wall = (float(v) for v in geom)
    half = w / 2 + wall
    return -half, h, [-half, half, -half, half], [h, h, -wall, -wall]


def sweep_constants(geom: Sequence[float]) -> Tensor:
    """(3, 4): lip offset (x, y, -) and each outer corner's (radius, angle) about the lip."""
    lx, ly, cx, cy = _sweep_geometry(geom)
    rx, ry = np.asarray(cx) - lx, np.asarray(cy) - ly
    return torch.tensor(np.stack([[lx, ly, 0.0, 0.0], np.hypot(rx, ry), np.arctan2(ry, rx)]), dtype=torch.float32)


def pour_sweep(s: Tensor, theta: Tensor, geom: Tensor, consts: Tensor | None = None) -> Tensor:
    """(x_min, x_max, y_min, y_max) of the cup's outer corners while tilting by theta about the lip.

    ``consts`` = :func:`sweep_constants` of ``geom`` (precomputed by the networks to save time).
    """
    c = (sweep_constants(geom.tolist()) if consts is None else consts).to(s.dtype)
    lx, ly = c[0, 0], c[0, 1]
    c0, s0 = torch.cos(s[:, 2]), torch.sin(s[:, 2])
    px = (s[:, 0] + c0 * lx - s0 * ly)[:, None, None]
    py = (s[:, 1] + s0 * lx + c0 * ly)[:, None, None]
    frac = torch.linspace(0.0, 1.0, SWEEP_STEPS, dtype=s.dtype)
    phi = c[2][None, :, None] + (s[:, 2:3] + theta[:, None] * frac)[:, None, :]  # (n, corners, steps)
    X = (px + c[1][None, :, None] * torch.cos(phi)).flatten(1)
    Y = (py + c[1][None, :, None] * torch.sin(phi)).flatten(1)
    xl, xh = torch.aminmax(X, dim=1)
    yl, yh = torch.aminmax(Y, dim=1)
    return torch.stack([xl, xh, yl, yh], 1)


def pour_sweep_np(s: np.ndarray, theta: np.ndarray, geom: Sequence[float]) -> np.ndarray:
    """Numpy twin of :func:`pour_sweep`."""
    return _pour_sweep_np(s, theta, _sweep_corners(geom))


def _sweep_corners(geom: Sequence[float]) -> tuple[float, float, np.ndarray, np.ndarray]:
    """Lip (x, y) and the outer corners relative to it (x, y arrays): what :func:`pour_sweep_np` needs of ``geom``."""
    lx, ly, cx, cy = _sweep_geometry(geom)
    return lx, ly, np.asarray(cx) - lx, np.asarray(cy) - ly


def _pour_sweep_np(
    s: np.ndarray, theta: np.ndarray, corners: tuple[float, float, np.ndarray, np.ndarray]
) -> np.ndarray:
    """:func:`pour_sweep_np` with the geometry's constants precomputed (the planner calls it per tree node)."""
    lx, ly, rx, ry = corners
    c0, s0 = np.cos(s[:, 2]), np.sin(s[:, 2])
    px = s[:, 0] + c0 * lx - s0 * ly
    py = s[:, 1] + s0 * lx + c0 * ly
    phi = s[:, 2:3] + theta[:, None] * _SWEEP_FRACTIONS[None, :]
    cp, sp = np.cos(phi)[..., None], np.sin(phi)[..., None]
    X = px[:, None, None] + cp * rx - sp * ry
    Y = py[:, None, None] + sp * rx + cp * ry
    return np.stack([X.min((1, 2)), X.max((1, 2)), Y.min((1, 2)), Y.max((1, 2))], 1)


def skill_features(
    skill: int, s: Tensor, p: Tensor, geom: Tensor | None = None, consts: Tensor | None = None
) -> Tensor:
    """Network inputs of one skill (before z-scoring); see ``FEATURE_DIMS``."""
    if skill == MOVE:
        return torch.cat([s, p, p - s[:, :2]], 1)
    g = torch.tensor(DEFAULT_CUP) if geom is None else geom
    return torch.cat([s, p, pour_sweep(s, p[:, 0], g, consts)], 1)


def nominal_pose(skill: int, s: Tensor, p: Tensor) -> Tensor:
    """Next pose if nothing gets in the way: move -> (x_cmd, y_cmd, theta), pour -> unchanged."""
    if skill == MOVE:
        return torch.cat([p, s[:, 2:3]], 1)
    return s[:, :3]


def project_fractions(v: Tensor) -> Tensor:
    """Clamp (v_ctrl, v_tgt) to [0, 1] and scale down if their sum exceeds 1."""
    v = v.clamp(0.0, 1.0)
    total = v.sum(1, keepdim=True)
    return torch.where(total > 1.0, v / total.clamp_min(1e-12), v)


_ACT = {"silu": nn.SiLU, "tanh": nn.Tanh, "relu": nn.ReLU}
_ACT_NP = {"silu": lambda h: h / (1.0 + np.exp(-h)), "tanh": np.tanh, "relu": lambda h: np.maximum(h, 0.0)}


def _silu_inplace(h: np.ndarray) -> None:
    t = np.negative(h)
    np.exp(t, out=t)
    t += 1.0
    np.divide(h, t, out=h)


#: the same arithmetic as ``_ACT_NP``, in place: the batch path's layers are [M, n, 128] arrays, and
#: allocating two temporaries per layer costs up to a quarter of its time at n = 256
_ACT_NP_INPLACE = {
    "silu": _silu_inplace,
    "tanh": lambda h: np.tanh(h, out=h),
    "relu": lambda h: np.maximum(h, 0.0, out=h),
}
_SWEEP_FRACTIONS = np.linspace(0.0, 1.0, SWEEP_STEPS)


def check_np_inputs(states: Any, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """Validated float64 (states [n, 5], actions [n, 3], skill ids [n], was-a-single-row) for the numpy path."""
    s = np.asarray(states, float)
    a = np.asarray(actions, float)
    single = s.ndim == 1
    if single:
        s, a = s[None], a[None]
    LearnedDynamics._check(s.shape, a.shape)
    if not (np.isfinite(s).all() and np.isfinite(a).all()):
        raise DynamicsError("dynamics.predict_np: states or actions contain NaN or inf")
    skill = np.rint(a[:, 0])
    bad = (np.abs(a[:, 0] - skill) > 1e-4) | ((skill != MOVE) & (skill != POUR))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise DynamicsError(f"dynamics.predict_np: action {i} has skill id {a[i, 0]:g}; allowed 0 (move) or 1 (pour)")
    return s, a, skill, single


def np_forward(w: dict, k: int, s: np.ndarray, p: np.ndarray, activation: str) -> np.ndarray:
    """Next states of skill ``k`` for rows s [n, 5], p [n, 2] from numpy weights ``w``.

    ``w["W"][i]`` is [in, out] for one network or [M, in, out] for M networks stacked (an ensemble:
    then ``b`` is [M, 1, out], ``pose_scale`` [M, 1, 3]); the result is [n, 5] or [M, n, 5]. The
    features are computed once for all M networks, and each layer is one batched matmul.
    """
    if k == MOVE:
        f = np.concatenate([s, p, p - s[:, :2]], 1)
        nominal = np.concatenate([p, s[:, 2:3]], 1)
    else:
        f = np.concatenate([s, p, _pour_sweep_np(s, p[:, 0], w["corners"])], 1)
        nominal = s[:, :3]
    h = f
    act = _ACT_NP_INPLACE[activation]
    last = len(w["W"]) - 1
    for i, (W, b) in enumerate(zip(w["W"], w["b"])):
        h = np.matmul(h, W)
        h += b
        if i < last:
            act(h)
    logits = h[..., 3:]
    e = np.exp(logits - logits.max(-1, keepdims=True))
    wts = e / e.sum(-1, keepdims=True)
    v = np.clip(s[:, 3:5], 0.0, 1.0)
    tot = v.sum(1, keepdims=True)
    v = np.where(tot > 1.0, v / np.maximum(tot, 1e-12), v)
    out = np.empty(h.shape[:-1] + (STATE_DIM,))
    out[..., :3] = nominal + h[..., :3] * w["pose_scale"]
    out[..., 3] = v[:, 0] * wts[..., 0]
    out[..., 4] = np.minimum(v[:, 1] + v[:, 0] * wts[..., 1], 1.0 - out[..., 3])
    return out


class SkillNet(nn.Module):
    """MLP of one skill plus its normalisation buffers."""

    def __init__(self, skill: int, hidden: Sequence[int], activation: str):
        super().__init__()
        self.skill = skill
        dims = [FEATURE_DIMS[skill], *hidden]
        layers: list[nn.Module] = []
        for a, b in zip(dims[:-1], dims[1:]):
            layers += [nn.Linear(a, b), _ACT[activation]()]
        layers.append(nn.Linear(dims[-1], OUT_DIM))
        self.mlp = nn.Sequential(*layers)
        with torch.no_grad():  # start at "nominal pose, water stays": small last layer, stay-biased logits
            self.mlp[-1].weight.mul_(0.1)
            self.mlp[-1].bias.zero_()
            self.mlp[-1].bias[3] = 2.0
        self.register_buffer("cup_geom", torch.tensor(DEFAULT_CUP, dtype=torch.float32))
        self.register_buffer("sweep_consts", sweep_constants(DEFAULT_CUP), persistent=False)
        self.register_buffer("in_mean", torch.zeros(FEATURE_DIMS[skill]))
        self.register_buffer("in_std", torch.ones(FEATURE_DIMS[skill]))
        self.register_buffer("pose_scale", torch.ones(3))
        self.register_buffer("frac_scale", torch.ones(2))
        self.register_buffer("trained", torch.zeros((), dtype=torch.bool))

    def forward(self, s: Tensor, p: Tensor) -> Tensor:
        z = (skill_features(self.skill, s, p, self.cup_geom, self.sweep_consts) - self.in_mean) / self.in_std
        out = self.mlp(z)
        pose = nominal_pose(self.skill, s, p) + out[:, :3] * self.pose_scale
        w = torch.softmax(out[:, 3:], 1)
        v = project_fractions(s[:, 3:5])
        vc = v[:, 0:1] * w[:, 0:1]
        vt = torch.minimum(v[:, 1:2] + v[:, 0:1] * w[:, 1:2], 1.0 - vc)  # min: float rounding only
        return torch.cat([pose, vc, vt], 1)

    def output_scale(self) -> Tensor:
        return torch.cat([self.pose_scale, self.frac_scale])

    def refresh_geometry(self) -> None:
        """Recompute the derived (not saved) sweep constants from ``cup_geom``."""
        self.sweep_consts.copy_(sweep_constants(self.cup_geom.tolist()))

    def set_statistics(self, s: np.ndarray, a: np.ndarray, s_next: np.ndarray, cfg: ModelConfig) -> None:
        """Normalisation from this skill's training transitions (floors keep scales positive)."""
        st, at, snt = (torch.as_tensor(x, dtype=torch.float32) for x in (s, a, s_next))
        p = at[:, 1:3]
        f = skill_features(self.skill, st, p, self.cup_geom, self.sweep_consts)
        self.in_mean.copy_(f.mean(0))
        self.in_std.copy_(f.std(0, unbiased=False).clamp_min(1e-3) if len(f) > 1 else torch.ones_like(self.in_std))
        res = snt[:, :3] - nominal_pose(self.skill, st, p)
        dv = snt[:, 3:5] - st[:, 3:5]
        if len(f) > 1:
            self.pose_scale.copy_(res.pow(2).mean(0).sqrt().clamp_min(cfg.min_pose_scale))
            self.frac_scale.copy_(dv.std(0, unbiased=False).clamp_min(cfg.min_fraction_scale))
        self.trained.fill_(True)


class LearnedDynamics(nn.Module):
    """f_hat(s, a) -> s' for the pouring state (x, y, theta, v_ctrl, v_tgt) and actions (skill, p1, p2).

    Satisfies ``planner.interfaces.DynamicsModel``. Construct with :meth:`load` or
    :func:`dynamics.load_or_train`; ``info`` holds the config, hashes and training metrics.
    """

    dtype = torch.float32
    device = torch.device("cpu")

    def __init__(self, cfg: ModelConfig | None = None, info: dict | None = None):
        super().__init__()
        self.cfg = cfg or ModelConfig()
        self.nets = nn.ModuleList([SkillNet(k, self.cfg.hidden, self.cfg.activation) for k in (MOVE, POUR)])
        self.info: dict[str, Any] = dict(info or {})
        self._np: list[dict] | None = None
        self.eval()

    # ------------------------------------------------------------------ torch API
    def forward(self, states: Tensor, actions: Tensor) -> Tensor:
        """Differentiable, unchecked batched prediction (training); use :meth:`predict` otherwise."""
        skill = actions[:, 0].round()
        is_pour = skill == POUR
        n_pour = int(is_pour.sum())
        if n_pour == 0:
            return self.nets[MOVE](states, actions[:, 1:3])
        if n_pour == len(states):
            return self.nets[POUR](states, actions[:, 1:3])
        out = states.new_empty(states.shape)
        for k, mask in ((MOVE, ~is_pour), (POUR, is_pour)):
            idx = mask.nonzero().squeeze(1)
            out[idx] = self.nets[k](states[idx], actions[idx, 1:3])
        return out

    def set_cup_geometry(self, inner_width: float, inner_height: float, wall: float) -> None:
        """Controlled cup dimensions (m) used by the pour network's swept-region inputs."""
        for net in self.nets:
            net.cup_geom.copy_(torch.tensor([inner_width, inner_height, wall], dtype=torch.float32))
            net.refresh_geometry()
        self._np = None

    def output_scale(self, actions: Tensor) -> Tensor:
        """Per-row loss scale (n, 5) of the skill of each action."""
        scales = torch.stack([net.output_scale() for net in self.nets])
        return scales[actions[:, 0].round().long()]

    @torch.no_grad()
    def predict(self, states: Tensor, actions: Tensor) -> Tensor:
        """Next states [n, 5] (float32) for states [n, 5] and actions [n, 3]; raises on bad input."""
        s = torch.as_tensor(states, dtype=torch.float32)
        a = torch.as_tensor(actions, dtype=torch.float32)
        self._check(s.shape, a.shape)
        if not (torch.isfinite(s).all() and torch.isfinite(a).all()):
            raise DynamicsError("dynamics.predict: states or actions contain NaN or inf")
        sk = a[:, 0]
        r = sk.round()
        bad = ((sk - r).abs() > 1e-4) | ((r != MOVE) & (r != POUR))
        if bad.any():
            i = int(bad.nonzero()[0])
            raise DynamicsError(
                f"dynamics.predict: action {i} has skill id {float(sk[i]):g}; allowed 0 (move) or 1 (pour)"
            )
        return self.forward(s, a)

    @staticmethod
    def _check(s_shape: Sequence[int], a_shape: Sequence[int]) -> None:
        if len(s_shape) != 2 or s_shape[1] != STATE_DIM:
            raise DynamicsError(
                f"dynamics.predict: states must have shape [n, {STATE_DIM}] (x, y, theta, v_ctrl, "
                f"v_tgt), got {tuple(s_shape)}"
            )
        if len(a_shape) != 2 or a_shape[1] != ACTION_DIM:
            raise DynamicsError(
                f"dynamics.predict: actions must have shape [n, {ACTION_DIM}] (skill_id, p1, p2), got {tuple(a_shape)}"
            )
        if s_shape[0] != a_shape[0]:
            raise DynamicsError(f"dynamics.predict: {s_shape[0]} states but {a_shape[0]} actions")

    # ------------------------------------------------------------------ numpy fast path
    def _weights(self) -> list[dict]:
        """Float64 numpy copies of the weights, input normalisation folded into the first layer."""
        if self._np is None:
            nets = []
            for net in self.nets:
                lin = [m for m in net.mlp if isinstance(m, nn.Linear)]
                W = [m.weight.detach().double().numpy().T.copy() for m in lin]
                b = [m.bias.detach().double().numpy().copy() for m in lin]
                mean, std = net.in_mean.double().numpy(), net.in_std.double().numpy()
                b[0] = b[0] - (mean / std) @ W[0]
                W[0] = W[0] / std[:, None]
                lx, ly, cx, cy = _sweep_geometry(net.cup_geom.tolist())
                rx, ry = np.asarray(cx) - lx, np.asarray(cy) - ly
                nets.append(
                    {
                        "W": W,
                        "b": b,
                        "pose_scale": net.pose_scale.double().numpy().copy(),
                        "geom": net.cup_geom.tolist(),
                        "corners": _sweep_corners(net.cup_geom.tolist()),
                        "lip": (lx, ly),
                        "radius": np.hypot(rx, ry)[:, None],
                        "angle": np.arctan2(ry, rx)[:, None],
                    }
                )
            self._np = nets
        return self._np

    def invalidate_cache(self) -> None:
        """Forget the numpy copy of the weights (call after changing parameters in place)."""
        self._np = None

    def load_state_dict(self, *args: Any, **kwargs: Any) -> Any:  # noqa: D102 - keeps derived copies in sync
        self._np = None
        out = super().load_state_dict(*args, **kwargs)
        for net in self.nets:
            net.refresh_geometry()
        return out

    def train(self, mode: bool = True) -> "LearnedDynamics":  # noqa: D102 - weights may change while training
        self._np = None
        return super().train(mode)

    def predict_np(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Numpy batch path (float64 arithmetic on the float32 weights); agrees with :meth:`predict` to ~1e-6."""
        s, a, skill, single = check_np_inputs(states, actions)
        out = np.empty_like(s)
        for k in (MOVE, POUR):
            m = skill == k
            if m.all():
                out = np_forward(self._weights()[k], k, s, a[:, 1:3], self.cfg.activation)
            elif m.any():
                out[m] = np_forward(self._weights()[k], k, s[m], a[m, 1:3], self.cfg.activation)
        return out[0] if single else out

    def predict_one(self, state: np.ndarray, action: np.ndarray) -> np.ndarray:
        """One transition, numpy in and out: the cheap path (no torch calls, few numpy calls).

        Same result as :meth:`predict_np` (float64 arithmetic) for a single (state, action).
        """
        s = np.asarray(state, float).reshape(-1)
        a = np.asarray(action, float).reshape(-1)
        if s.shape != (STATE_DIM,) or a.shape != (ACTION_DIM,):
            raise DynamicsError(
                f"dynamics.predict_one: expected a state of {STATE_DIM} and an action of "
                f"{ACTION_DIM} numbers, got shapes {np.shape(state)} and {np.shape(action)}"
            )
        x, y, th, vc, vt = (float(v) for v in s)
        kf, p1, p2 = (float(v) for v in a)
        if not all(map(math.isfinite, (x, y, th, vc, vt, kf, p1, p2))):
            raise DynamicsError("dynamics.predict_one: state or action contains NaN or inf")
        k = int(round(kf))
        if abs(kf - k) > 1e-4 or k not in (MOVE, POUR):
            raise DynamicsError(f"dynamics.predict_one: skill id {kf:g}; allowed 0 (move) or 1 (pour)")
        w = self._weights()[k]
        if k == MOVE:
            f = np.array([x, y, th, vc, vt, p1, p2, p1 - x, p2 - y])
            nominal = (p1, p2, th)
        else:  # swept bounding box, as pour_sweep_np but on one row
            lx, ly = w["lip"]
            c0, s0 = math.cos(th), math.sin(th)
            px, py = x + c0 * lx - s0 * ly, y + s0 * lx + c0 * ly
            phi = w["angle"] + (th + p1 * _SWEEP_FRACTIONS)[None, :]
            X = px + w["radius"] * np.cos(phi)
            Y = py + w["radius"] * np.sin(phi)
            f = np.array([x, y, th, vc, vt, p1, p2, X.min(), X.max(), Y.min(), Y.max()])
            nominal = (x, y, th)
        h = f
        n_layers = len(w["W"])
        for i in range(n_layers):
            h = h @ w["W"][i] + w["b"][i]
            if i < n_layers - 1:
                h = _ACT_NP[self.cfg.activation](h)
        e = np.exp(h[3:] - h[3:].max())
        e /= e.sum()
        vc, vt = min(max(vc, 0.0), 1.0), min(max(vt, 0.0), 1.0)
        if vc + vt > 1.0:
            vc, vt = vc / (vc + vt), vt / (vc + vt)
        pose = np.asarray(nominal) + h[:3] * w["pose_scale"]
        vc_next = vc * e[0]
        return np.array([pose[0], pose[1], pose[2], vc_next, min(vt + vc * e[1], 1.0 - vc_next)])

    # ------------------------------------------------------------------ checkpoints
    def save(self, path: str | Path) -> Path:
        """Atomic checkpoint: format tag, model config, ``info`` (config, hashes, metrics), weights + statistics."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        payload = {
            "format": CHECKPOINT_FORMAT,
            "version": MODEL_FORMAT_VERSION,
            "model_config": json.dumps(
                {
                    "hidden": list(self.cfg.hidden),
                    "activation": self.cfg.activation,
                    "min_pose_scale": self.cfg.min_pose_scale,
                    "min_fraction_scale": self.cfg.min_fraction_scale,
                }
            ),
            "info": json.dumps(self.info, default=safeio.json_default),
            "state_dict": {k: v.detach().clone() for k, v in self.state_dict().items()},
        }
        atomic_torch_save(payload, path)
        return path

    @classmethod
    def load(cls, path: str | Path, expected_hash: str | None = None) -> "LearnedDynamics":
        """Load a checkpoint; ``expected_hash`` (the config's model hash) guards against a stale one."""
        path = Path(path)
        payload, fix = load_tagged(path, "checkpoint", CHECKPOINT_FORMAT, MODEL_FORMAT_VERSION, "retrain", "train")
        try:
            mcfg = ModelConfig(**json.loads(payload["model_config"]))
            info = json.loads(payload["info"])
            model = cls(mcfg, info)
            model.load_state_dict(payload["state_dict"], strict=True)
        except (KeyError, TypeError, ValueError, RuntimeError, json.JSONDecodeError) as e:
            raise DynamicsError(
                f"dynamics checkpoint {path} does not match this model code ({type(e).__name__}: {str(e)[:300]}); {fix}"
            ) from None
        if expected_hash is not None and info.get("model_hash") != expected_hash:
            raise DynamicsError(
                f"dynamics checkpoint {path} was trained with another config (hash "
                f"{info.get('model_hash')}, expected {expected_hash}); {fix}"
            )
        model.eval()
        return model
