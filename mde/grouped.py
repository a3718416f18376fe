"""One GP MDE (:class:`mde.GPMDE`) per value of a categorical feature (the action's skill).

The pouring task's action is (skill, p1, p2): p1, p2 are a move's target (x, y) or a pour's
(angle, hold). One stationary ARD kernel over both has to share a length scale between a target x
in metres and an angle in radians, and lets moves inform pours; its pour predictions then barely
generalise (measured on 128 target-world trajectories, held out by trajectory: one GP admits 19 %
of the pours whose true deviation is under d_max, one GP per skill 65 %, neither admits a bad
one). Groups are independent: a row's prediction depends only on its own group's
data; a group without data predicts the prior (mean 0, std ``prior_std``), "unknown".
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any, Mapping

import torch
from botorch.posteriors.gpytorch import GPyTorchPosterior
from torch import Tensor

import safeio

from .config import MDEConfig
from .gp import DTYPE, MarginalModel
from .model import GPMDE, _as_labels, _as_matrix

_FORMAT = "mde.GroupedMDE"
#: 2: every group is saved as an ``mde.GPMDE``
_FORMAT_VERSION = 2


class GroupedMDE:
    """``fit(X, y)``, ``predict(X) -> (mean, std)`` and a BoTorch ``model``, like
    :class:`GPMDE`, with one such GP per value of ``config.group_column``.

    With ``group_column=None`` every row is in one group: results equal one GPMDE.
    """

    def __init__(self, config: MDEConfig | Mapping[str, Any] | None = None, **overrides: Any) -> None:
        base = config.to_dict() if isinstance(config, MDEConfig) else MDEConfig.from_dict(config).to_dict()
        base.update(overrides)
        self._config = MDEConfig.from_dict(base)
        self._child_config = dataclasses.replace(self._config, group_column=None)
        self._children: dict[float, GPMDE] = {}
        self._prior = GPMDE(self._child_config)
        self._X: Tensor | None = None
        self._y: Tensor | None = None
        self._n_features: int | None = None

    # -- properties ------------------------------------------------------------------------------
    @property
    def config(self) -> MDEConfig:
        return self._config

    @property
    def is_fitted(self) -> bool:
        return any(c.is_fitted for c in self._children.values())

    @property
    def n_train(self) -> int:
        return 0 if self._X is None else int(self._X.shape[0])

    @property
    def n_features(self) -> int | None:
        return self._n_features

    @property
    def train_X(self) -> Tensor | None:
        """All rows of the last fit, in the order given (not grouped)."""
        return self._X

    @property
    def train_y(self) -> Tensor | None:
        return self._y

    @property
    def groups(self) -> dict[float, GPMDE]:
        """The GP of each group value seen in fitting."""
        return dict(self._children)

    @property
    def fit_info(self) -> dict[str, Any]:
        return {f"group {g:g}": c.fit_info for g, c in self._children.items()}

    @property
    def model(self) -> MarginalModel:
        """BoTorch model of the per-row marginals, each row's from its group's GP (label units; rows of different
        groups are independent by construction, rows of one group come with their marginal variances only,
        a diagonal covariance: what the trajectory acquisitions read). See :class:`mde.gp.MarginalModel`."""
        return MarginalModel(self)

    @property
    def marginal_model(self) -> MarginalModel:
        """The same as :attr:`model` (the acquisitions' view of every MDE kind)."""
        return MarginalModel(self)

    def posterior(self, X: Tensor, observation_noise: bool = False) -> GPyTorchPosterior:
        return self.model.posterior(X, observation_noise=observation_noise)

    # -- fitting and prediction ------------------------------------------------------------------
    def group_of(self, X: Tensor) -> Tensor:
        """Group value of each row of ``X`` (... x d) -> (...)."""
        col = self._config.group_column
        if col is None:
            return torch.zeros(X.shape[:-1], dtype=DTYPE)
        if col >= X.shape[-1]:
            raise ValueError(f"group_column={col} but X has only {X.shape[-1]} feature columns")
        return X[..., col].detach().to(DTYPE).cpu()

    def fit(self, X: Any, y: Any) -> "GroupedMDE":
        """Fit every group's GP on its rows (each keeps its previous fit if its new one fails)."""
        X = _as_matrix(X, "X").to(DTYPE)
        y = _as_labels(y, X.shape[0])
        g = self.group_of(X)
        for value in torch.unique(g).tolist():
            rows = g == value
            child = self._children.get(value) or GPMDE(self._child_config)
            self._children[value] = child.fit(X[rows], y[rows])
        for value in set(self._children) - set(torch.unique(g).tolist()):
            self._children[value].fit(X[:0], y[:0])  # no rows left: back to the prior
        self._X, self._y, self._n_features = X, y, int(X.shape[1])
        return self

    def _check_query(self, X: Any, name: str = "X") -> Tensor:
        X = _as_matrix(X, name)
        if self._n_features is not None and X.shape[1] != self._n_features:
            raise ValueError(f"{name} has d={X.shape[1]} features but the MDE was fitted with d={self._n_features}")
        return X

    def _route(self, X: Any, fn: str, **kwargs: Any) -> list[Tensor]:
        X = self._check_query(X)
        g = self.group_of(X)
        outs: list[Tensor] | None = None
        for value in torch.unique(g).tolist():
            rows = g == value
            res = getattr(self._children.get(value, self._prior), fn)(X[rows], **kwargs)
            res = res if isinstance(res, tuple) else (res,)
            if outs is None:
                outs = [torch.empty(X.shape[0], dtype=r.dtype) for r in res]
            for o, r in zip(outs, res):
                o[rows] = r
        return outs if outs is not None else [torch.zeros(0, dtype=X.dtype), torch.zeros(0, dtype=X.dtype)]

    def predict(self, X: Any) -> tuple[Tensor, Tensor]:
        """Mean and predictive std of the deviation at ``X`` (n x d), label units, no autograd."""
        mean, std = self._route(X, "predict")
        return mean, std

    def mean_var(self, X: Any, observation_noise: bool = True) -> tuple[Tensor, Tensor]:
        """Mean and variance at ``X`` (n x d), each row's from its group's GP (label units, no autograd)."""
        mean, var = self._route(X, "mean_var", observation_noise=observation_noise)
        return mean, var

    def covariance(self, Xa: Any, Xb: Any) -> Tensor:
        """Latent posterior covariance ``a x b`` (label units, float64): within a group its GP's, across groups 0
        (the groups are independent GPs)."""
        Xa, Xb = self._check_query(Xa, "Xa"), self._check_query(Xb, "Xb")
        ga, gb = self.group_of(Xa), self.group_of(Xb)
        out = torch.zeros(Xa.shape[0], Xb.shape[0], dtype=torch.float64)
        for value in set(torch.unique(ga).tolist()) & set(torch.unique(gb).tolist()):
            ra, rb = ga == value, gb == value
            block = self._children.get(value, self._prior).covariance(Xa[ra], Xb[rb])
            out[ra.nonzero().squeeze(-1).unsqueeze(-1), rb.nonzero().squeeze(-1)] = block
        return out

    def noise_std(self, X: Any) -> Tensor:
        """Std of the observation noise alone at ``X`` (label units)."""
        return self._route(X, "noise_std")[0]

    # -- persistence -----------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> Path:
        """Write config, data and every group's fitted state to ``path`` atomically."""
        payload = {
            "format": _FORMAT,
            "version": _FORMAT_VERSION,
            "config": self._config.to_dict(),
            "n_features": self._n_features,
            "X": self._X,
            "y": self._y,
            "groups": [(g, c.to_payload()) for g, c in self._children.items()],
        }
        return safeio.save_torch(Path(path), payload)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "GroupedMDE":
        """Rebuild a saved GroupedMDE; predictions are identical to the saved one's."""
        payload = torch.load(Path(path), map_location="cpu", weights_only=True)
        if not isinstance(payload, dict) or payload.get("format") != _FORMAT:
            tag = payload.get("format") if isinstance(payload, dict) else None
            raise ValueError(f"{path} is not a saved {_FORMAT} (format tag {tag!r}); fit the MDE again")
        if payload.get("version") != _FORMAT_VERSION:
            raise ValueError(
                f"{path} has format version {payload.get('version')}, this code reads version "
                f"{_FORMAT_VERSION}; fit the MDE again"
            )
        mde = cls(payload["config"])
        mde._n_features, mde._X, mde._y = payload["n_features"], payload["X"], payload["y"]
        mde._children = {float(g): GPMDE.from_payload(p, f"{path} group {g}") for g, p in payload["groups"]}
        return mde

    def __repr__(self) -> str:
        parts = ", ".join(f"{g:g}: {c.n_train}" for g, c in sorted(self._children.items()))
        return f"GroupedMDE(group_column={self._config.group_column}, n_train per group {{{parts}}})"


def load(path: str | os.PathLike) -> GPMDE | GroupedMDE:
    """Load a saved MDE of either kind (the file names its format)."""
    payload = torch.load(Path(path), map_location="cpu", weights_only=True)
    cls = GroupedMDE if isinstance(payload, dict) and payload.get("format") == _FORMAT else GPMDE
    return cls.load(path)
