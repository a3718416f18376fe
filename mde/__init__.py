"""Model deviation estimator (MDE): a Gaussian process on BoTorch / GPyTorch.

Predicts a Gaussian over the deviation d(f_hat(s, a), s') of an inaccurate dynamics model from
features X = (s, a). Knows nothing of the simulator or the planner: tensors in, tensors out.
:class:`GPMDE` is one GP whose noise is either homoscedastic (one level) or the paper's most-likely
heteroscedastic model (``MDEConfig.heteroscedastic``).

    from mde import GPMDE
    mde = GPMDE().fit(X, y)                      # X: n x d, y: n deviations >= 0
    mean, std = mde.predict(X_query)             # label units, predictive std (latent + noise)
    post = mde.model.posterior(X_bqd)            # BoTorch posterior, label units, latent only
    mde = GroupedMDE(group_column=5)             # one such GP per value of feature 5 (the skill)
"""

from typing import Any

from .config import MDEConfig
from .grouped import GroupedMDE, load
from .model import GPMDE

__all__ = ["GroupedMDE", "GPMDE", "MDEConfig", "calibration_report", "load"]


def __getattr__(name: str) -> Any:
    # Lazy, so that ``python -m mde.calibration`` does not find its own module imported already.
    if name == "calibration_report":
        from .calibration import calibration_report

        return calibration_report
    raise AttributeError(f"module 'mde' has no attribute {name!r}")
