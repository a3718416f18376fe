"""Acquisition functions built from the configuration, for an MDE and a method's keyword arguments.

The configured acquisition (``configs/acquisition/``) is a ``_partial_`` spec instantiated with
``hydra.utils.instantiate``; a method may bring its own spec (``methods.<name>.acquisition._target_``).
"""

from __future__ import annotations

import inspect
import json
from typing import Any, Mapping

from hydra.utils import get_class, instantiate

from .acquisition import ACQUISITIONS, check_gamma
from .experiment import ExperimentConfig


def acquisition_factory(acq_cfg: Mapping[str, Any], exp: ExperimentConfig):
    """Build the configured acquisition (``configs/acquisition/``, a ``_partial_`` spec instantiated with
    ``hydra.utils.instantiate``) for an MDE and a method's keyword arguments (``c``; each passed only
    if the class accepts it, as is ``d_max`` = experiment.d_max and ``beta`` = experiment.beta_test unless the
    spec sets them, and ``reference``: the features of the transitions a look-ahead acquisition scores for).

    A method whose ``acquisition:`` names a ``_target_`` brings its own spec (e.g. ``active_straddle``), built
    the same way instead of the configured one, so that one run can compare acquisitions side by side."""
    cfg = dict(acq_cfg)
    if "_target_" not in cfg:
        raise ValueError("acquisition._target_ is missing: e.g. active.acquisition.DiscountedMaxUCB")
    cls = acquisition_class(cfg["_target_"], "acquisition")
    takes = _keywords(cls) - {"model"}
    unknown = sorted(set(cfg) - {"_target_", "_partial_"} - takes)
    if unknown:  # refused before compute: a partial would only fail when the first candidate is scored
        raise ValueError(
            f"acquisition.{unknown[0]} = {cfg[unknown[0]]!r}: not a parameter of {cfg['_target_']}; "
            f"allowed {sorted(takes)}"
        )
    if "gamma" in cfg:
        check_gamma(cfg["gamma"])
    cfg["_partial_"] = True  # a method's own spec need not say it
    partial = instantiate(cfg, _convert_="all")
    params = inspect.signature(cls.__init__).parameters

    own: dict[str, Any] = {}  # a method's own spec (its acquisition: names a _target_) -> its factory

    def make(mde: Any, method_kwargs: Mapping[str, Any] | None = None, reference: Any = None):
        method_kwargs = dict(method_kwargs or {})
        if "_target_" in method_kwargs:
            key = json.dumps(method_kwargs, sort_keys=True, default=str)
            if key not in own:
                own[key] = acquisition_factory(method_kwargs, exp)
            return own[key](mde, None, reference)
        kw = {k: v for k, v in method_kwargs.items() if k in params}
        if "d_max" in params and "d_max" not in partial.keywords:
            kw["d_max"] = exp.d_max
        if "beta" in params and "beta" not in partial.keywords and "beta" not in kw:
            kw["beta"] = exp.beta_test  # a look-ahead acquisition's precondition is the test planner's
        if "reference" in params and reference is not None:
            kw["reference"] = reference
        # an MDE's marginal view reads its fit's own factorisation (GPyTorch's refactorisation can fail on it)
        model = getattr(mde, "marginal_model", None)
        model = getattr(mde, "model", mde) if model is None else model
        return partial(model=model, **kw)

    make.accepts = _keywords(cls) - {"model"}  # type: ignore[attr-defined]
    make.target = cfg["_target_"]  # type: ignore[attr-defined]
    return make


def acquisition_class(target: str, where: str) -> type:
    """The class an acquisition spec's ``_target_`` names, or an error naming ``where`` and the built-in ones."""
    try:
        return get_class(target)
    except Exception as e:
        raise ValueError(
            f"{where}._target_ = {target!r} cannot be imported ({e}); built in: "
            f"{sorted(c.__module__ + '.' + c.__name__ for c in ACQUISITIONS.values())}"
        ) from None


def check_method_acquisition(name: str, method: Any, make_acquisition: Any) -> None:
    """Refuse, before compute, a method's acquisition keyword that no acquisition takes (a typo would
    otherwise do nothing). A keyword of another built-in acquisition (the paper's ``c`` with
    ``acquisition=variance``) is allowed: the configured one ignores it, as documented. A method's own spec
    (``acquisition._target_``) must import and take each of its keywords."""
    spec = dict(getattr(method, "acquisition", None) or {})
    if "_target_" in spec:  # the method's own acquisition: its keywords must be its class's
        takes = _keywords(acquisition_class(spec["_target_"], f"methods.{name}.acquisition")) - {"model"}
        unknown = sorted(set(spec) - {"_target_", "_partial_"} - takes)
        if unknown:
            raise ValueError(
                f"methods.{name}.acquisition: {unknown} is not a parameter of {spec['_target_']}; "
                f"it takes {sorted(takes)}"
            )
        return
    kwargs = set(spec)
    built_in = set().union(*(_keywords(cls) for cls in ACQUISITIONS.values()))
    unknown = sorted(kwargs - set(make_acquisition.accepts) - built_in)
    if unknown:
        raise ValueError(
            f"methods.{name}.acquisition: {unknown} is a parameter of no acquisition; "
            f"{make_acquisition.target} takes {sorted(make_acquisition.accepts)}"
        )


def _keywords(cls: type) -> frozenset[str]:
    """The named parameters of ``cls``'s constructor (not ``self``, ``*args`` or ``**kwargs``)."""
    params = inspect.signature(cls.__init__).parameters.items()
    return frozenset(k for k, p in params if k != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD))
