"""The data-collection methods: how one training trajectory is chosen for a problem.

* ``random_actions``: a fixed number of actions from the planner's action sampler (no planning);
* ``random_plan``: a uniformly random candidate among the planner's candidates that reach the goal;
* ``model_plan``: the same among candidates planned with the model alone (no MDE precondition): the non-adaptive
  baseline, which asks whether the MDE's say in data collection helps at all;
* ``active_cautious`` / ``active_mean`` / ``active_balanced``: the candidate that maximises the
  configured acquisition function (by default the paper's alpha with c = -0.1 / 0 / 0.1);
* ``oracle``: not a method but a bound (:mod:`active.oracle`): every candidate executed, the one whose data most
  improve the test planner's success on held-out validation problems kept.

The methods are specs in the ``methods:`` node of the run config (``configs/methods/default.yaml``:
name -> ``_target_`` and its arguments), built with ``hydra.utils.instantiate``: a new method is a YAML
entry or an override (``methods.active_balanced.acquisition.c=0.2``, ``+methods.mine._target_=...``;
for a new choice rule, a subclass of :class:`Method`). If the planner finds no candidate, a method falls
back to random actions and the trajectory is marked ``fallback`` (recorded in categories.csv), so every
iteration still collects data;
with ``experiment.fallback=model_plan`` the loop replaces those by a plan of the model alone (``fallback_plan``).
If an active method's acquisition fails numerically (a singular MDE posterior), it executes a random
candidate instead, warns, and marks it ``plan_unscored``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Callable, Mapping

import numpy as np
import torch
from linear_operator.utils.errors import NanError, NotPSDError

import configs

#: numerical failures of an MDE posterior that an active method survives (a random candidate instead)
SCORING_ERRORS = (NotPSDError, NanError, torch.linalg.LinAlgError)

#: the shipped registry of methods (name -> instantiable spec), the ``methods:`` node a run gets by default
METHODS_FILE = configs.path("methods", "default.yaml")


@dataclass
class Choice:
    actions: np.ndarray  # (T, 3)
    #: "plan", "random_actions", "fallback" (random actions), "fallback_plan" (experiment.fallback) or
    #: "plan_unscored" (the acquisition failed numerically; a random candidate was executed)
    source: str
    n_candidates: int
    scores: list[float] | None = None
    chosen: int | None = None


class Method:
    """How a training trajectory is chosen. ``plans``: whether the planner's candidates are needed;
    ``plans_with_mde``: whether they are planned under the MDE's precondition (False: the model alone);
    ``acquisition``: keyword arguments for the acquisition (None: the method uses none)."""

    plans: bool = True
    plans_with_mde: bool = True
    acquisition: dict[str, Any] | None = None

    def choose(
        self,
        candidates: list,
        rng: np.random.Generator,
        random_actions: Callable[[], np.ndarray],
        make_acquisition: Callable[[Mapping[str, Any]], Any] | None = None,
    ) -> Choice:
        raise NotImplementedError  # pragma: no cover - abstract


class RandomActions(Method):
    plans = False

    def choose(self, candidates, rng, random_actions, make_acquisition=None) -> Choice:
        return Choice(random_actions(), "random_actions", 0)


class OracleBound(Method):
    """The oracle bound (:mod:`active.oracle`): the loop executes every candidate and keeps the one whose data score
    best, so it chooses after execution, not here. ``score``: ``success`` (the test planner's success, with an MDE
    fitted on the data plus the candidate's, on ``validation_problems`` held-out target-world problems: the endpoint
    itself) or ``admission`` (the test precondition's admission of good minus bad transitions on
    ``validation_trajectories`` held-out target-world trajectories: cheaper, refuted by a pilot, results/headroom)."""

    SCORES = ("success", "admission")

    def __init__(
        self, score: str = "success", validation_problems: int = 10, validation_trajectories: int = 64
    ) -> None:
        if score not in self.SCORES:
            raise ValueError(f"oracle: score = {score!r}: allowed one of {list(self.SCORES)}")
        if int(validation_problems) < 1:
            raise ValueError(f"oracle: validation_problems = {validation_problems!r}: allowed an integer >= 1")
        if int(validation_trajectories) < 2:
            raise ValueError(f"oracle: validation_trajectories = {validation_trajectories!r}: allowed an integer >= 2")
        self.score = score
        self.validation_problems = int(validation_problems)
        self.validation_trajectories = int(validation_trajectories)

    def choose(self, candidates, rng, random_actions, make_acquisition=None) -> Choice:
        raise TypeError("the oracle chooses after executing every candidate (active.loop.MethodRun), not before")


class RandomPlan(Method):
    def choose(self, candidates, rng, random_actions, make_acquisition=None) -> Choice:
        if not candidates:
            return Choice(random_actions(), "fallback", 0)
        k = int(rng.integers(len(candidates)))
        return Choice(np.asarray(candidates[k].actions), "plan", len(candidates), chosen=k)


class ModelPlan(RandomPlan):
    """A random candidate of the planner with the model alone: the data the MDE learns from are then the trajectories
    the model itself believes in, whatever the MDE has learnt (half of the ladder's ceiling data are of this kind)."""

    plans_with_mde = False


class ActiveChoice(Method):
    """The candidate that maximises the acquisition (BoTorch convention), each candidate one q-batch."""

    def __init__(self, acquisition: Mapping[str, Any] | None = None) -> None:
        self.acquisition = dict(acquisition or {})

    def choose(self, candidates, rng, random_actions, make_acquisition=None) -> Choice:
        if not candidates:
            return Choice(random_actions(), "fallback", 0)
        acq = make_acquisition(self.acquisition)
        scores = []
        try:
            with torch.no_grad():
                for cand in candidates:  # candidates differ in length: one q-batch each
                    X = torch.as_tensor(np.asarray(cand.features), dtype=torch.float64).unsqueeze(0)
                    scores.append(float(acq(X).item()))
        except SCORING_ERRORS as err:  # one bad MDE state must not end a long run: recorded, run goes on
            warnings.warn(
                f"acquisition failed on {len(candidates)} candidates ({type(err).__name__}: {err}); "
                "executing a random candidate, recorded as source 'plan_unscored'",
                RuntimeWarning,
                stacklevel=2,
            )
            k = int(rng.integers(len(candidates)))
            return Choice(np.asarray(candidates[k].actions), "plan_unscored", len(candidates), chosen=k)
        k = int(np.argmax(scores))  # BoTorch convention: acquisitions are maximised
        return Choice(np.asarray(candidates[k].actions), "plan", len(candidates), scores=scores, chosen=k)


@lru_cache(maxsize=1)
def method_specs() -> dict[str, dict]:
    """name -> spec, as the shipped ``configs/methods/default.yaml`` gives them."""
    from omegaconf import OmegaConf

    return _checked(OmegaConf.to_container(OmegaConf.load(METHODS_FILE), resolve=True), str(METHODS_FILE))


def _checked(specs: Any, where: str) -> dict[str, dict]:
    if not isinstance(specs, Mapping) or not all(isinstance(v, Mapping) and "_target_" in v for v in specs.values()):
        raise ValueError(f"{where}: expected a mapping name -> {{_target_: ..., ...}}")
    return {str(k): dict(v) for k, v in specs.items()}


class _Names(Mapping):
    """The shipped method names (a read-only view of the registry, for membership tests and messages)."""

    def __getitem__(self, name: str) -> dict:
        return method_specs()[name]

    def __iter__(self):
        return iter(method_specs())

    def __len__(self) -> int:
        return len(method_specs())


METHODS: Mapping[str, dict] = _Names()


def check_method(name: str, registry: Mapping[str, Any] | None = None) -> str:
    """``name`` if ``registry`` (default: the shipped one) has it, else an error naming the allowed ones."""
    names = METHODS if registry is None else _checked(registry, "methods")
    if name not in names:
        raise ValueError(
            f"method = {name!r}: allowed one of {sorted(names)} (the methods: node, configs/methods/default.yaml)"
        )
    return name


def build_method(name: str, registry: Mapping[str, Any] | None = None) -> Method:
    """The method ``name`` of ``registry`` (a run's ``methods:`` node; default: the shipped one), instantiated."""
    from hydra.utils import instantiate

    specs = METHODS if registry is None else _checked(registry, "methods")
    spec = dict(specs[check_method(name, specs)])
    # a method's own acquisition spec (acquisition._target_) is built later, with the MDE: not instantiated here
    own_acquisition = isinstance(spec.get("acquisition"), Mapping) and "_target_" in spec["acquisition"]
    method = instantiate(spec, _convert_="all", _recursive_=not own_acquisition)
    if not isinstance(method, Method):
        raise ValueError(f"method {name!r}: {type(method).__name__} is not an active.methods.Method")
    return method


def choose(
    method: str | Method,
    candidates: list,
    rng: np.random.Generator,
    random_actions: Callable[[], np.ndarray],
    make_acquisition: Callable[[Mapping[str, Any]], Any] | None = None,
) -> Choice:
    """Pick the trajectory to execute from the planner's candidates (each has ``.features`` [T, d]
    and ``.actions`` [T, 3])."""
    m = build_method(method) if isinstance(method, str) else method
    return m.choose(candidates, rng, random_actions, make_acquisition)
