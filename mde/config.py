"""Configuration of the model deviation estimator (MDE).

One frozen dataclass so that a run's resolved config can be written next to its results and a
saved model can be rebuilt exactly; ``configs/mde/default.yaml`` lists the same fields for Hydra.
Every field is validated on construction: a bad value raises ``ValueError`` naming the field and
what is allowed, because a silently wrong GP setting only shows up much later as a bad planner.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Mapping

import yaml

ALLOWED_NU = (0.5, 1.5, 2.5)
ALLOWED_INPUT_SCALING = ("none", "normalize")
ALLOWED_PREDICT_DTYPE = ("float32", "float64")
ALLOWED_PRIORS = ("none", "gamma", "lognormal")

#: Keys a Hydra node may carry that are not MDE settings.
_HYDRA_KEYS = ("_target_", "_recursive_", "_convert_", "_partial_")


@dataclass(frozen=True)
class MDEConfig:
    """Settings of :class:`mde.GPMDE` (paper defaults where the paper says).

    Units: ``prior_std`` is in label units (the deviation's own units); ``noise_floor`` and
    ``jitter`` are in z-scored label units, i.e. fractions of the label variance.
    """

    #: Smoothness of the Matern kernel (ARD, inside a ScaleKernel).
    nu: float = 2.5
    #: Upper bound of every ARD lengthscale (mean and noise GP), in standard deviations of that
    #: input over the GP's training points; None: unbounded. Keeps the log-noise GP from smoothing
    #: over a whole input's range (BENCHMARKS.md, admission: what an MDE admits).
    lengthscale_max: float | None = None
    #: The same bound for the log-noise GP alone (None: ``lengthscale_max``). Why: a noise GP that
    #: smooths over the whole pour region puts the scatter of its spills on the safe pours between
    #: them, while a mean GP bounded as tightly interpolates its data.
    noise_lengthscale_max: float | None = None
    #: Lower bound of the mean GP's latent std far from its data, in label units (an outputscale
    #: bound of ``(latent_std_min / label std)^2``); None: unbounded. Why: the labels are z-scored,
    #: so a GP that has seen only small deviations (or fits an outputscale near 0) predicts a narrow
    #: std wherever it has no data, and its precondition then admits transitions it knows nothing
    #: about. With ``latent_std_min >= d_max / 2`` an unvisited
    #: transition fails ``mu + 2 sigma < d_max`` as it does before any data.
    latent_std_min: float | None = None
    #: Upper bound of the same latent std, label units (outputscale <= ``(latent_std_max / label std)^2``);
    #: None: unbounded. Why: a maximum-likelihood fit on labels of a small spread (mostly clean pours, few at
    #: ``label_max``) picks a z-scored outputscale 2-3x that of one whose data include failures, and its
    #: uncertainty then grows faster away from its own pours.
    latent_std_max: float | None = None
    #: Labels above this (label units) are fitted as this value; None: as they are. Why: the
    #: precondition only asks whether mu + beta sigma < d_max, so every deviation well above d_max
    #: is equally "not admitted", while a few whole spills (pour labels up to ~2, against an admitted
    #: bulk below 0.07) dominate the z-scoring and push the GP either to interpolate them with tiny
    #: noise or to call every pour noise (BENCHMARKS.md, ceiling: which MDE and plant model). Must stay
    #: well above d_max.
    label_max: float | None = None
    #: Hyperparameter priors of every GP (mean and log-noise): "none" (maximum likelihood) or "gamma"
    #: (BoTorch's SingleTaskGP defaults until 0.12, current when the paper was written: lengthscale
    #: Gamma(3, 6) in the kernel's input units, outputscale Gamma(2, 0.15), noise Gamma(1.1, 0.05);
    #: the fit is then MAP). Why: free fits on the MDE's data go to lengthscales of tens of metres or
    #: an outputscale near 0; a prior keeps them in range softly, where ``lengthscale_max`` cuts them
    #: off. "lognormal" (the default): BoTorch's defaults since 0.12 (Hvarfner et al. 2024): lengthscale /
    #: input range ~ LogNormal(sqrt 2 + log(d) / 2, sqrt 3), noise LogNormal(-4, 1) on z-scored labels; it keeps
    #: small-data fits off the optima where the noise goes to the floor or a lengthscale to 0, and lifts the
    #: quick experiment significantly (BENCHMARKS.md, ceiling and experiment: BoTorch's hyperparameter priors).
    hyperparameter_priors: str = "lognormal"
    #: Most-likely heteroscedastic GP (True, the paper's) or a homoscedastic GP (False: one noise level; with
    #: ``label_max`` the pouring task's default, configs/mde/default.yaml).
    heteroscedastic: bool = True
    #: "none": raw (s, a) features as in the paper; "normalize": BoTorch ``Normalize`` with the
    #: bounds of the training inputs.
    input_scaling: str = "none"
    #: Predictive std (label units) reported before any data: mean 0 and this std. 1.0 is far above
    #: the pouring task's d_max = 0.07, so an untrained MDE is "unknown everywhere": it admits every
    #: transition under the optimistic training beta (-2) and none under the test beta (+2).
    prior_std: float = 1.0
    #: Cap on the most-likely heteroscedastic iterations (noise GP refits).
    max_iters: int = 5
    #: Stop iterating when the mean GP's log marginal likelihood per point improves by less.
    min_improvement: float = 1e-3
    #: Lower bound of the noise variance, z-scored units (fraction of the label variance).
    noise_floor: float = 1e-4
    #: First jitter (fraction of the mean diagonal) tried when a Cholesky fails; x10 per retry.
    jitter: float = 1e-6
    #: Number of jitter retries before the factorisation is declared failed.
    max_jitter_tries: int = 4
    #: L-BFGS-B iterations per GP hyperparameter fit (``fit_gpytorch_mll``).
    fit_maxiter: int = 150
    #: Hyperparameters are fitted on at most this many points (a seeded random subset); the
    #: fitted GP then conditions on all points. 0 means "always all points".
    max_fit_points: int = 2000
    #: Seed of the subset above (the only randomness in fitting).
    seed: int = 0
    #: dtype of the cached batched prediction path (fitting is always float64).
    predict_dtype: str = "float64"  # float32 is faster but lost all precision on real simulator features
    #: Rows per chunk in batched prediction (keeps the kernel block in cache).
    predict_chunk: int = 1024
    #: Torch intra-op threads during fit/predict (restored afterwards; :func:`task.threads.torch_threads`);
    #: 0 keeps torch's setting. On a CPU shared with other busy processes 1 is faster and much steadier
    #: than 2 (OpenMP threads wait on each other); on an idle machine torch's default is best.
    num_threads: int = 0
    #: Index of a categorical feature column (e.g. the action's skill): :class:`mde.GroupedMDE`
    #: fits one independent GP per value of that column. Skills' parameters mean different
    #: things (a move's target x against a pour's angle), so one stationary kernel across them
    #: is a poor prior. None: one GP for all rows (:class:`mde.GPMDE`).
    group_column: int | None = None

    def __post_init__(self) -> None:
        if isinstance(self.nu, bool) or not isinstance(self.nu, (int, float)) or float(self.nu) not in ALLOWED_NU:
            raise ValueError(f"nu must be one of {ALLOWED_NU}, got {self.nu!r}")
        object.__setattr__(self, "nu", float(self.nu))
        if not isinstance(self.heteroscedastic, bool):
            raise ValueError(f"heteroscedastic must be true or false, got {self.heteroscedastic!r}")
        if self.input_scaling not in ALLOWED_INPUT_SCALING:
            raise ValueError(f"input_scaling must be one of {ALLOWED_INPUT_SCALING}, got {self.input_scaling!r}")
        if self.hyperparameter_priors not in ALLOWED_PRIORS:
            raise ValueError(
                f"hyperparameter_priors must be one of {ALLOWED_PRIORS}, got {self.hyperparameter_priors!r}"
            )
        if self.predict_dtype not in ALLOWED_PREDICT_DTYPE:
            raise ValueError(f"predict_dtype must be one of {ALLOWED_PREDICT_DTYPE}, got {self.predict_dtype!r}")
        if self.lengthscale_max is not None:
            _positive_float(self, "lengthscale_max")
        if self.noise_lengthscale_max is not None:
            _positive_float(self, "noise_lengthscale_max")
        if self.latent_std_min is not None:
            _positive_float(self, "latent_std_min")
        if self.latent_std_max is not None:
            _positive_float(self, "latent_std_max")
            if self.latent_std_min is not None and self.latent_std_min >= self.latent_std_max:
                raise ValueError(
                    f"latent_std_min ({self.latent_std_min}) must be below latent_std_max ({self.latent_std_max})"
                )
        if self.label_max is not None:
            _positive_float(self, "label_max")
        _positive_float(self, "prior_std")
        _positive_float(self, "noise_floor")
        _positive_float(self, "jitter")
        _nonneg_float(self, "min_improvement")
        _int_at_least(self, "max_iters", 1)
        _int_at_least(self, "max_jitter_tries", 0)
        _int_at_least(self, "fit_maxiter", 1)
        _int_at_least(self, "max_fit_points", 0)
        _int_at_least(self, "seed", 0)
        _int_at_least(self, "predict_chunk", 1)
        _int_at_least(self, "num_threads", 0)
        if self.group_column is not None:
            _int_at_least(self, "group_column", 0)
        if 0 < self.max_fit_points < 2:
            raise ValueError(f"max_fit_points must be 0 (all points) or >= 2, got {self.max_fit_points!r}")

    @property
    def noise_lengthscale_bound(self) -> float | None:
        """The lengthscale bound the log-noise GP is built with."""
        return self.lengthscale_max if self.noise_lengthscale_max is None else self.noise_lengthscale_max

    # -- construction helpers ------------------------------------------------------------------
    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | None) -> "MDEConfig":
        """Build from a plain or OmegaConf mapping; Hydra's ``_target_`` keys are ignored.

        Unknown keys raise ``ValueError`` (a typo in a sweep must not be silently dropped).
        """
        values = dict(values or {})
        for key in _HYDRA_KEYS:
            values.pop(key, None)
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown MDE config field(s) {unknown}; allowed fields: {sorted(known)}")
        return cls(**values)

    @classmethod
    def from_yaml(cls, path: str | Path) -> "MDEConfig":
        """Read a YAML file such as ``configs/mde/default.yaml``."""
        with open(path, encoding="utf-8") as fh:
            return cls.from_dict(yaml.safe_load(fh))

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (for saving with a model and for logging the resolved config)."""
        return asdict(self)


def _positive_float(cfg: MDEConfig, name: str) -> None:
    value = getattr(cfg, name)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    object.__setattr__(cfg, name, float(value))


def _nonneg_float(cfg: MDEConfig, name: str) -> None:
    value = getattr(cfg, name)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    object.__setattr__(cfg, name, float(value))


def _int_at_least(cfg: MDEConfig, name: str, lo: int) -> None:
    value = getattr(cfg, name)
    if isinstance(value, bool) or not isinstance(value, int) or value < lo:
        raise ValueError(f"{name} must be an integer >= {lo}, got {value!r}")
