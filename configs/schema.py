"""The schema of the run config (``python -m active.run``): every leaf's type, finiteness, range and choices.

Why: a value of the wrong type or out of range must be refused before any compute, with a message that names the
field's full dotted path, the value and what is allowed, not turn into a ``TypeError`` deep inside the code or a
run that "succeeds" with a meaningless result (``experiment.beta_test=nan`` used to fail every test plan and
exit 0). :func:`check_config` validates a composed config against :class:`RunConfig` (pydantic models, one per
config group) and raises :class:`ConfigFieldError`; ``active.run.prepare_run`` calls it first.

The ranges and choices are those of the code that consumes each field (``sim.engine.config.SimConfig``,
``sim.world.WorldConfig``, ``dynamics.config``, ``mde.config.MDEConfig``, ``planner.config.PlannerConfig``,
``active.experiment.ExperimentConfig``, ``active.acquisition``, ``active.methods``, ``active.run``,
``active.preflight``; ``tests/test_config_fields.py`` keeps the choices in sync with them); where the code has
none, the physically obvious one (a probability in [0, 1], a length or a time step > 0, a count >= 0 or >= 1).
Relations between fields that need the world's geometry or the solver's stability bound stay with those
consumers, which also run before compute.

Imports nothing of this project (``configs`` is a leaf package that every package may import).
"""

import math
import re
from dataclasses import dataclass, replace
from typing import Annotated, Any, Literal, Mapping, Optional, Union, get_args, get_origin

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, WrapValidator, model_validator
from pydantic_core import InitErrorDetails, PydanticCustomError

__all__ = ["ConfigFieldError", "Rule", "RunConfig", "check_config", "format_path", "rule_for", "split_path"]

#: choices, as the consuming code spells them (tests/test_config_fields.py compares them with the code's constants)
ARCHES = ("cpu", "gpu", "auto")  # sim.engine.config.ARCHES
BOX_NORMALS = ("analytic", "central")  # sim.engine.config.BOX_NORMALS
PLANT_CONTACT = ("stop", "hold", "stuck")  # sim.world.PLANT_CONTACT
ACTIVATIONS = ("silu", "tanh", "relu")  # dynamics.config.ACTIVATIONS
LOSSES = ("distance", "scaled_mse")  # dynamics.config.LOSSES
LR_SCHEDULES = ("constant", "cosine")  # dynamics.config.LR_SCHEDULES
NU = (0.5, 1.5, 2.5)  # mde.config.ALLOWED_NU
INPUT_SCALING = ("none", "normalize")  # mde.config.ALLOWED_INPUT_SCALING
PREDICT_DTYPES = ("float32", "float64")  # mde.config.ALLOWED_PREDICT_DTYPE
PRIORS = ("none", "gamma", "lognormal")  # mde.config.ALLOWED_PRIORS
OMPL_LOG_LEVELS = ("none", "error", "warn", "info", "debug")  # planner.config._LOG_LEVELS
FALLBACKS = ("random_actions", "model_plan")  # active.experiment.ALLOWED_FALLBACKS
RUNNERS = ("sequential", "lockstep")  # active.run.RUNNERS
WANDB_MODES = ("offline", "online", "disabled")  # active.run.WANDB_MODES
#: seeds feed numpy's SeedSequence and torch.manual_seed (active.preflight.MAX_SEED)
MAX_SEED = 2**32 - 1
#: actions per plan or trajectory: the world's skills.max_actions allows 1..6 (sim.world.WorldConfig.validate)
MAX_ACTIONS = 6
#: columns of the MDE's features: the state (5) and the action (skill, p1, p2)
N_FEATURES = 8
#: the keyword arguments of the built-in acquisitions (``active.acquisition``; ``model`` and ``reference`` are
#: the loop's, not the config's)
ACQUISITION_PARAMS = {
    "active.acquisition.DiscountedMaxUCB": ("c", "gamma", "observation_noise"),
    "active.acquisition.DiscountedMaxLCB": ("c", "gamma", "observation_noise"),
    "active.acquisition.TrajectoryStraddle": ("d_max", "kappa", "gamma", "observation_noise"),
    "active.acquisition.TrajectoryVariance": ("gamma", "observation_noise"),
    "active.acquisition.TrajectoryThompson": ("seed", "gamma", "observation_noise"),
    "active.acquisition.TrajectoryAdmissionGain": ("d_max", "beta", "observation_noise"),
}
#: the keyword arguments of the built-in methods (``active.methods``)
METHOD_PARAMS = {
    "active.methods.RandomActions": (),
    "active.methods.RandomPlan": (),
    "active.methods.ModelPlan": (),
    "active.methods.ActiveChoice": ("acquisition",),
    "active.methods.OracleBound": ("score", "validation_problems", "validation_trajectories"),
}
#: the oracle bound's fields of a method spec (:class:`Method`)
ORACLE_FIELDS = METHOD_PARAMS["active.methods.OracleBound"]
#: Hydra's keys of an instantiable spec that the acquisition factory accepts besides the class's parameters
SPEC_KEYS = ("_target_", "_partial_")


class ConfigFieldError(ValueError):
    """One or more config fields are invalid; the message has one line per field:
    ``<full.dotted.path> = <value!r>: allowed <what>``. ``fields`` holds (path, value, allowed) per line."""

    def __init__(self, fields: list[tuple[str, Any, str]]) -> None:
        self.fields = fields
        super().__init__("\n".join(f"{p} = {v!r}: {why}" for p, v, why in fields))


# ------------------------------------------------------------------------------------------------ leaf types
@dataclass(frozen=True)
class Rule:
    """What a leaf allows, in words (``allowed``) and as bounds (the tests probe just outside them)."""

    allowed: str
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    integer: bool = False
    choices: tuple | None = None


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def _say(rule: Rule, list_level: bool = False) -> WrapValidator:
    """pydantic validates; this replaces its message by the leaf's ``allowed`` (element errors of a list keep
    their own message and path)."""

    def wrap(value: Any, handler: Any) -> Any:
        try:
            return handler(value)
        except ValidationError as e:
            if list_level and all(err["loc"] for err in e.errors()):
                raise
            raise PydanticCustomError("config_value", "{allowed}", {"allowed": rule.allowed}) from None

    return WrapValidator(wrap)


def _leaf(base: Any, rule: Rule, *constraints: Any) -> Any:
    return Annotated[(base, *constraints, rule, _say(rule))]


def number(gt: float | None = None, ge: float | None = None, lt: float | None = None, le: float | None = None) -> Any:
    """A finite real number (an integer is one; a bool or a string is not) within the bounds given."""
    low = f"({_num(gt)}" if gt is not None else f"[{_num(ge)}" if ge is not None else None
    high = f"{_num(lt)})" if lt is not None else f"{_num(le)}]" if le is not None else None
    if low and high:
        allowed = f"{low}, {high}"  # an interval of finite ends: finite
    elif low:
        allowed = f"{'>' if gt is not None else '>='} {low[1:]} (a finite number)"
    elif high:
        allowed = f"{'<' if lt is not None else '<='} {high[:-1]} (a finite number)"
    else:
        allowed = "a finite number"
    return _leaf(
        float,
        Rule(allowed, gt=gt, ge=ge, lt=lt, le=le),
        Field(strict=True, allow_inf_nan=False, gt=gt, ge=ge, lt=lt, le=le),
    )


def integer(ge: int | None = None, le: int | None = None) -> Any:
    """An integer (not a bool, not a float such as 4.0) within the bounds given."""
    if ge is not None and le is not None:
        allowed = f"an integer in [{ge}, {le}]"
    elif ge is not None:
        allowed = f"an integer >= {ge}"
    elif le is not None:
        allowed = f"an integer <= {le}"
    else:
        allowed = "an integer"
    return _leaf(int, Rule(allowed, ge=ge, le=le, integer=True), Field(strict=True, ge=ge, le=le))


def seed_value(ge: int = 0, le: int = MAX_SEED) -> Any:
    """A seed of numpy's SeedSequence and torch.manual_seed."""
    return integer(ge=ge, le=le)


def one_of(*choices: Any) -> Any:
    """One of ``choices`` (strings or numbers), as the consuming code's tuple of allowed values."""
    return _leaf(Literal[choices], Rule(f"one of {choices!r}", choices=choices))


def flag() -> Any:
    return _leaf(bool, Rule("true or false"), Field(strict=True))


def text() -> Any:
    return _leaf(str, Rule("a non-empty string"), Field(strict=True, min_length=1))


_DOTTED = r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)+$"


def dotted() -> Any:
    """An importable name, e.g. ``active.acquisition.DiscountedMaxUCB`` (whether it imports is checked by its user)."""
    return _leaf(
        str, Rule("a dotted import path, e.g. active.acquisition.DiscountedMaxUCB"), Field(strict=True, pattern=_DOTTED)
    )


def _rule_of(t: Any) -> Rule:
    return next(m for m in get_args(t)[1:] if isinstance(m, Rule))


def nullable(t: Any) -> Any:
    """null (YAML's ``null``: the consumer's documented default) or ``t``."""
    rule = _rule_of(t)
    rule = replace(rule, allowed=f"null or {rule.allowed}")
    return Annotated[Optional[t], rule, _say(rule)]


def listing(
    elem: Any, length: int | None = None, min_length: int | None = None, allowed: str | None = None, check: Any = None
) -> Any:
    """A list of ``elem``; each element is validated (and named: ``path[i]``) on its own."""
    what = _rule_of(elem).allowed
    rule = Rule(allowed or f"a list of {length if length else f'at least {min_length or 0}'}, each {what}")
    extra = [AfterValidator(check)] if check else []
    return Annotated[
        (
            list[elem],
            Field(min_length=length or min_length, max_length=length),
            *extra,
            rule,
            _say(rule, list_level=True),
        )
    ]


def _ordered(v: list) -> list:
    if v[0] > v[1]:
        raise PydanticCustomError("config_value", "order")
    return v


def pair(elem: Any = None) -> Any:
    """A ``[low, high]`` range with low <= high."""
    elem = elem if elem is not None else number()
    return listing(
        elem, length=2, check=_ordered, allowed=f"a [low, high] pair with low <= high, each {_rule_of(elem).allowed}"
    )


# ------------------------------------------------------------------------------------------------ groups
class Group(BaseModel):
    """A config group: unknown keys are refused (a typo must not be silently ignored), NaN and infinities too;
    every leaf's strictness is its type's (``number``, ``integer``, ...): lists may also be tuples."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=False)


def _error(loc: tuple, value: Any, message: str) -> InitErrorDetails:
    return InitErrorDetails(
        type=PydanticCustomError("config_key", "{message}", {"message": message}), loc=loc, input=value
    )


def _raise(title: str, errors: list[InitErrorDetails]) -> None:
    if errors:
        raise ValidationError.from_exception_data(title, errors)


def _non_finite(value: Any, loc: tuple = ()) -> list[tuple[tuple, Any]]:
    """Where a value of unknown type (a custom class's argument) holds NaN or an infinity."""
    if isinstance(value, float) and not math.isfinite(value):
        return [(loc, value)]
    if isinstance(value, Mapping):
        return [x for k, v in value.items() for x in _non_finite(v, (*loc, k))]
    if isinstance(value, (list, tuple)):
        return [x for i, v in enumerate(value) for x in _non_finite(v, (*loc, i))]
    return []


# --- world (sim.world.WorldConfig, sim.engine.config.SimConfig)
class Sim(Group):
    """``world.sim``: SimConfig's fields (defaults there); ``n_envs`` is the runs' own, not a world setting."""

    dim: one_of(2) = 2  # the pouring world is planar: (x, y, theta) poses, 2-D shapes
    domain: listing(number(gt=0), length=2) = None
    dx: number(gt=0) = None
    dt: number(gt=0) = None  # <= cfl * dx / sound_speed: SimConfig.validate
    rho: number(gt=0) = None
    sound_speed: number(gt=0) = None
    gravity: number(ge=0) = None
    friction: number(ge=0, le=10) = None
    viscosity: number(ge=0) = None
    tension: flag() = None
    volume_correction: flag() = None
    volume_relax: number(gt=0) = None  # s, a time constant: the solver divides by it
    stretch_relax: number(ge=0) = None
    boundary_density: flag() = None
    box_normals: one_of(*BOX_NORMALS) = None
    ppc: integer(ge=1) = None  # a perfect power k**dim: SimConfig.validate
    max_particles: integer(ge=1) = None
    max_bodies: integer(ge=1) = None
    max_shapes: integer(ge=1) = None
    wall_cells: integer(ge=2) = None
    cfl: number(gt=0, le=1) = None
    arch: one_of(*ARCHES) = None
    deterministic: flag() = None
    seed: seed_value() = None
    jitter: number(ge=0, le=0.5) = None


class Cup(Group):
    inner_width: number(gt=0)
    inner_height: number(gt=0)
    wall: number(gt=0)
    fill_height: number(ge=0) = None
    x: number() = None


class Leaf(Group):
    """An ellipse of the plant, in the plant's frame."""

    center: listing(number(), length=2)
    radii: listing(number(gt=0), length=2)
    angle: number()


class Plant(Group):
    stem_x: number()
    stem_height: number(gt=0)
    stem_radius: number(gt=0)
    leaves: listing(
        Annotated[Leaf, Rule("a leaf {center: [x, y], radii: [a, b], angle}")],
        allowed="a list of leaves, each {center: [x, y], radii: [a, b], angle}",
    )
    jitter_xy: number(ge=0)
    jitter_tilt: number(ge=0)
    on_contact: one_of(*PLANT_CONTACT) = None


class Move(Group):
    x: pair()
    y: pair()
    peak_speed: number(gt=0)


class Pour(Group):
    theta: pair()
    hold: pair(number(ge=0))
    peak_rate: number(gt=0)


class Skills(Group):
    move: Move
    pour: Pour
    settle: number(ge=0)
    max_actions: integer(ge=1, le=MAX_ACTIONS)
    clip_parameters: flag() = None
    lattice: number(ge=0, le=0.05) = None


class Problems(Group):
    start_x: pair()
    start_y: pair()
    goal: pair(number(ge=0, le=1))
    tolerance: number(gt=0, le=1)
    max_spill: number(ge=0, le=1)


def _some_weight(w: list) -> list:
    if not any(v > 0 for v in w):
        raise PydanticCustomError("config_value", "all 0")
    return w


class DistanceWeights(Group):
    pose: number(ge=0) = 1.0
    volume: number(ge=0) = 1.0

    @model_validator(mode="after")
    def _not_all_zero(self) -> "DistanceWeights":
        if not (self.pose > 0 or self.volume > 0):
            _raise(
                "distance_weights",
                [_error((), {"pose": self.pose, "volume": self.volume}, "allowed weights >= 0, not both 0")],
            )
        return self


class World(Group):
    sim: Sim
    control_dt: number(gt=0)  # >= sim.dt: WorldConfig.validate
    controlled_cup: Cup
    target_cup: Cup
    plant: Plant
    skills: Skills
    problems: Problems
    distance_weights: DistanceWeights = None


# --- dynamics (dynamics.config)
class Data(Group):
    seed: integer(ge=0) = None
    n_batches: integer(ge=1) = None
    batch_size: integer(ge=1) = None
    min_actions: integer(ge=1, le=MAX_ACTIONS) = None
    max_actions: integer(ge=1, le=MAX_ACTIONS) = None  # >= min_actions: DataConfig
    max_sim_seconds: number(gt=0) = None
    p_problem_start: number(ge=0, le=1) = None
    p_pour: number(ge=0, le=1) = None
    p_pour_after_pour: number(ge=0, le=1) = None
    p_near_target: number(ge=0, le=1) = None
    p_pour_after_near: number(ge=0, le=1) = None
    pour_theta_focus: pair() = None
    p_theta_focus: number(ge=0, le=1) = None
    near_target_dx: pair() = None
    near_target_y: pair() = None
    p_keep_stuck: number(ge=0, le=1) = None
    p_keep_stuck_pour: number(ge=0, le=1) = None
    start_margin: number(ge=0) = None
    pour_batches: integer(ge=0) = None
    pour_x: pair() = None
    pour_y: pair() = None
    pour_theta: pair() = None
    p_second_pour: number(ge=0, le=1) = None
    world: nullable(text()) = None


class Model(Group):
    hidden: listing(integer(ge=1), min_length=1) = None
    activation: one_of(*ACTIVATIONS) = None
    min_pose_scale: number(gt=0) = None
    min_fraction_scale: number(gt=0) = None
    ensemble: integer(ge=1) = None


class Train(Group):
    seed: integer(ge=0) = None
    loss: one_of(*LOSSES) = None
    val_fraction: number(gt=0, lt=1) = None
    max_epochs: integer(ge=1) = None
    batch_size: integer(ge=1) = None
    lr: number(gt=0) = None
    weight_decay: number(ge=0) = None
    patience: integer(ge=1) = None
    lr_schedule: one_of(*LR_SCHEDULES) = None
    threads: integer(ge=1) = None


class Eval(Group):
    seed: integer(ge=0) = None
    source_batches: integer(ge=0) = None
    target_batches: integer(ge=0) = None
    near_radius: number(ge=0) = None
    stream_speed: number(ge=0) = None


class Dynamics(Group):
    cache_root: text() = None
    progress: flag() = None
    data: Data = None
    model: Model = None
    train: Train = None
    eval: Eval = None


# --- mde (mde.config.MDEConfig)
class MDE(Group):
    target: dotted() = Field(alias="_target_")
    group_column: nullable(integer(ge=0, le=N_FEATURES - 1)) = None
    nu: one_of(*NU) = None
    lengthscale_max: nullable(number(gt=0)) = None
    noise_lengthscale_max: nullable(number(gt=0)) = None
    latent_std_min: nullable(number(gt=0)) = None  # < latent_std_max: MDEConfig
    latent_std_max: nullable(number(gt=0)) = None
    label_max: nullable(number(gt=0)) = None
    hyperparameter_priors: one_of(*PRIORS) = None
    heteroscedastic: flag() = None
    input_scaling: one_of(*INPUT_SCALING) = None
    prior_std: number(gt=0) = None
    max_iters: integer(ge=1) = None
    min_improvement: number(ge=0) = None
    noise_floor: number(gt=0) = None
    jitter: number(gt=0) = None
    max_jitter_tries: integer(ge=0) = None
    fit_maxiter: integer(ge=1) = None
    max_fit_points: integer(ge=0) = None  # 0 (all points) or >= 2: checked below
    seed: integer(ge=0) = None
    predict_dtype: one_of(*PREDICT_DTYPES) = None
    predict_chunk: integer(ge=1) = None
    num_threads: integer(ge=0) = None

    @model_validator(mode="after")
    def _fit_points(self) -> "MDE":
        if self.max_fit_points == 1:
            _raise("mde", [_error(("max_fit_points",), 1, "allowed 0 (all points) or an integer >= 2")])
        return self


# --- planner (planner.config.PlannerConfig; the keys interpolated from world / experiment as there)
class Planner(Group):
    target: dotted() = Field(None, alias="_target_")
    state_low: listing(number(), length=5) = None
    state_high: listing(number(), length=5) = None
    move_x: pair() = None
    move_y: pair() = None
    pour_theta: pair() = None
    pour_hold: pair(number(ge=0)) = None
    p_move: number(ge=0, le=1) = None
    max_actions: integer(ge=1, le=MAX_ACTIONS) = None
    spill_limit: number(ge=0, le=1) = None
    d_max: number(gt=0) = None
    n_candidates: integer(ge=1) = None
    time_budget: number(gt=0) = None
    propagation_budget: integer(ge=1) = None
    goal_bias: number(ge=0, le=1) = None
    batch_min: integer(ge=1) = None
    batch_max: integer(ge=1) = None
    last_step_proposals: integer(ge=1) = None
    distance_weights: listing(
        number(ge=0), length=4, check=_some_weight, allowed="4 finite numbers >= 0, not all 0"
    ) = None
    clip_to_bounds: flag() = None
    prune_dead_states: flag() = None
    stuck_tilt: number(gt=0) = None
    stuck_move: number(gt=0) = None
    torch_threads: integer(ge=0) = None
    ompl_log_level: one_of(*OMPL_LOG_LEVELS) = None
    workers: Annotated[
        Union[integer(ge=1), Literal["auto"]],
        Rule("an integer >= 1 (1 = plan in the main process) or 'auto'", ge=1, integer=True),
        _say(Rule("an integer >= 1 (1 = plan in the main process) or 'auto'")),
    ] = None

    @model_validator(mode="after")
    def _ordered(self) -> "Planner":
        errors = []
        if self.state_low is not None and self.state_high is not None:
            errors += [
                _error(("state_high", i), hi, f"allowed >= state_low[{i}] = {lo!r}")
                for i, (lo, hi) in enumerate(zip(self.state_low, self.state_high))
                if hi < lo
            ]
        if self.batch_min is not None and self.batch_max is not None and self.batch_max < self.batch_min:
            errors.append(_error(("batch_max",), self.batch_max, f"allowed an integer >= batch_min = {self.batch_min}"))
        _raise("planner", errors)
        return self


# --- experiment (active.experiment.ExperimentConfig)
class Experiment(Group):
    name: text() = None
    methods: listing(text(), min_length=1) = None  # each a name in the methods: node (RunConfig)
    iterations: integer(ge=1) = None
    trajectories_per_iteration: integer(ge=1) = None
    refit_every: integer(ge=1) = None
    candidates: integer(ge=1) = None
    test_problems: integer(ge=1) = None
    random_actions_length: integer(ge=1, le=MAX_ACTIONS) = None
    d_max: number(gt=0) = None
    beta_train: listing(number(), length=2, allowed="[beta_early, beta_late], two finite numbers") = None
    beta_switch_iteration: integer(ge=0) = None
    beta_test: number() = None
    calibration_trajectories: integer(ge=1) = None
    planner_propagation_budget: integer(ge=1) = None
    planner_time_budget: number(gt=0) = None
    known_obstacles: flag() = None
    refine_steps: integer(ge=0) = None
    refine_lr: number(gt=0) = None
    plan_goal_tol: nullable(number(gt=0, le=1)) = None  # <= world.problems.tolerance: active.planner_setup
    plan_accept_tol: nullable(number(gt=0, le=1)) = None
    plan_spill_limit: nullable(number(ge=0, le=1)) = None
    fallback: one_of(*FALLBACKS) = None


# --- acquisition (active.acquisition; a _partial_ spec) and methods (active.methods)
class AcquisitionArgs(Group):
    """A method's ``acquisition:`` (keyword arguments for the configured acquisition, or, with ``_target_``, an
    acquisition spec of its own); every built-in keyword is typed here. A spec of a built-in class takes only that
    class's parameters; other classes' parameters are theirs to check (here: finite)."""

    model_config = ConfigDict(extra="allow")

    target: dotted() = Field(None, alias="_target_")
    partial: flag() = Field(None, alias="_partial_")
    c: number() = None
    gamma: number(gt=0, le=1) = None
    kappa: number(ge=0) = None
    seed: integer(ge=-(2**63), le=2**63 - 1) = None  # hashed as 8 signed bytes (TrajectoryThompson)
    d_max: number(gt=0) = None
    beta: number() = None
    observation_noise: flag() = None

    def given(self) -> dict[str, Any]:
        """The keys set, by their config name, with their values."""
        fields = type(self).model_fields
        out = {fields[k].alias or k: getattr(self, k) for k in self.model_fields_set if k in fields}
        return {**out, **(self.model_extra or {})}

    @model_validator(mode="after")
    def _parameters(self) -> "AcquisitionArgs":
        given = self.given()
        if self.target in ACQUISITION_PARAMS:
            allowed = sorted((*SPEC_KEYS, *ACQUISITION_PARAMS[self.target]))
            _raise(
                "acquisition",
                [
                    _error((k,), v, f"not a parameter of {self.target}; allowed keys: {allowed}")
                    for k, v in given.items()
                    if k not in allowed
                ],
            )
        elif self.target is not None:
            _raise(
                "acquisition",
                [
                    _error((k, *loc), v, "allowed a finite number")
                    for k, v in (self.model_extra or {}).items()
                    for loc, v in _non_finite(v)
                ],
            )
        return self


class Acquisition(AcquisitionArgs):
    """The configured acquisition (``configs/acquisition/``)."""

    target: dotted() = Field(alias="_target_")


class Method(Group):
    """A method spec (``configs/methods/default.yaml``): a built-in class takes only its parameters."""

    model_config = ConfigDict(extra="allow")

    target: dotted() = Field(alias="_target_")
    acquisition: Optional[AcquisitionArgs] = None
    score: one_of("success", "admission") = None  # active.methods.OracleBound (OracleBound.SCORES)
    validation_problems: integer(ge=1) = None  # active.methods.OracleBound
    validation_trajectories: integer(ge=2) = None  # active.methods.OracleBound

    @model_validator(mode="after")
    def _parameters(self) -> "Method":
        given = {
            "_target_": self.target,
            **({"acquisition": self.acquisition} if "acquisition" in self.model_fields_set else {}),
            **{k: getattr(self, k) for k in ORACLE_FIELDS if k in self.model_fields_set},
            **(self.model_extra or {}),
        }
        if self.target in METHOD_PARAMS:
            allowed = sorted(("_target_", *METHOD_PARAMS[self.target]))
            _raise(
                "method",
                [
                    _error(
                        (k,),
                        v.given() if isinstance(v, AcquisitionArgs) else v,
                        f"not a parameter of {self.target}; allowed keys: {allowed}",
                    )
                    for k, v in given.items()
                    if k not in allowed
                ],
            )
        else:
            _raise(
                "method",
                [
                    _error((k, *loc), v, "allowed a finite number")
                    for k, v in (self.model_extra or {}).items()
                    for loc, v in _non_finite(v)
                ],
            )
        return self


class Wandb(Group):
    mode: one_of(*WANDB_MODES) = None
    project: text() = None
    entity: nullable(text()) = None


_SEEDS_ALLOWED = "null (the run uses seed) or a non-empty list, e.g. seeds=[0,1,2]"


def _seeds_unique(v: Any) -> Any:
    if v is not None and len(set(v)) != len(v):
        raise PydanticCustomError("config_value", "{allowed}", {"allowed": "each seed at most once"})
    return v


class RunConfig(Group):
    """The whole config of ``python -m active.run`` (``configs/config.yaml`` with its groups)."""

    world: World
    dynamics: Dynamics
    mde: MDE
    experiment: Experiment  # before planner: the keys planner: interpolates are named at their source first
    planner: Planner
    acquisition: Acquisition
    methods: dict[str, Method]
    wandb: Wandb = None
    method: text() = "all"  # "all" or a name in methods: (checked below)
    seed: seed_value()
    seeds: Annotated[
        Optional[listing(seed_value(), min_length=1, allowed=_SEEDS_ALLOWED)],
        Rule(f"{_SEEDS_ALLOWED}", ge=0, le=MAX_SEED, integer=True),
        _say(Rule(_SEEDS_ALLOWED), True),
        AfterValidator(_seeds_unique),
    ] = None
    runner: one_of(*RUNNERS) = None
    progress: flag() = None

    @model_validator(mode="after")
    def _names(self) -> "RunConfig":
        """Method names refer to the methods: node; a method's keyword arguments to an acquisition."""
        names = sorted(self.methods)
        errors = []
        if self.method != "all" and self.method not in self.methods:
            errors.append(
                _error(
                    ("method",),
                    self.method,
                    f"allowed one of {names + ['all']} (a name in the "
                    "methods: node, configs/methods/default.yaml, or all)",
                )
            )
        errors += [
            _error(("experiment", "methods", i), m, f"allowed one of {names} (the methods: node)")
            for i, m in enumerate(self.experiment.methods or ())
            if m not in self.methods
        ]
        built_in = sorted({k for ks in ACQUISITION_PARAMS.values() for k in ks})
        configured = self.acquisition.target
        for name, spec in self.methods.items():
            acq = spec.acquisition
            if acq is None or acq.target is not None:
                continue
            for k, v in (acq.model_extra or {}).items():
                loc = ("methods", name, "acquisition", k)
                if configured in ACQUISITION_PARAMS:
                    errors.append(_error(loc, v, f"a parameter of no acquisition; allowed keys: {built_in}"))
                else:  # the configured acquisition is a custom class: its parameters are its own
                    errors += [_error((*loc, *sub), x, "allowed a finite number") for sub, x in _non_finite(v)]
        _raise("run config", errors)
        return self


# ------------------------------------------------------------------------------------------------ checking
def check_config(cfg: Mapping[str, Any]) -> Mapping[str, Any]:
    """Validate a composed run config (a plain or OmegaConf mapping; Hydra's own ``hydra:`` node aside) against
    :class:`RunConfig`; raise :class:`ConfigFieldError` naming every invalid field, else return ``cfg`` as it is
    (the run keeps using its mappings: the schema is the check, not a conversion)."""
    data = _plain(cfg)
    data.pop("hydra", None)
    try:
        RunConfig.model_validate(data)
    except ValidationError as e:
        raise ConfigFieldError([_explain(err) for err in e.errors(include_url=False)]) from None
    return cfg


def _plain(v: Any) -> Any:
    if isinstance(v, Mapping):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)) or (
        hasattr(v, "__iter__") and hasattr(v, "__len__") and not isinstance(v, (str, bytes, Mapping))
    ):
        return [_plain(x) for x in v]
    return v


def _explain(err: Mapping[str, Any]) -> tuple[str, Any, str]:
    """(path, value, what is allowed) of one pydantic error."""
    loc, kind, ctx = tuple(err["loc"]), err["type"], err.get("ctx") or {}
    path = format_path(loc)
    if kind == "config_value":
        return path, err["input"], f"allowed {ctx['allowed']}"
    if kind == "config_key":
        return path, err["input"], ctx["message"]
    if kind == "extra_forbidden":
        model = _annotation_at(loc[:-1])[0]
        keys = sorted(f.alias or k for k, f in model.model_fields.items()) if _is_model(model) else []
        return path, err["input"], f"not a key of {format_path(loc[:-1]) or 'the run config'}; allowed keys: {keys}"
    if kind == "missing":
        return path, None, "missing: a required key"
    if kind in ("model_type", "model_attributes_type", "dict_type"):
        return path, err["input"], "allowed a mapping (a config group)"
    return path, err.get("input"), f"allowed {err['msg']}"  # pragma: no cover - every leaf says its own


# ------------------------------------------------------------------------------------------------ paths
def format_path(loc: tuple) -> str:
    """``('world', 'plant', 'leaves', 0, 'center', 1)`` -> ``world.plant.leaves[0].center[1]``."""
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def split_path(path: str) -> tuple:
    """The inverse of :func:`format_path`."""
    return tuple(int(p) if p.isdigit() else p for p in re.findall(r"[^.\[\]]+", path))


def _is_model(t: Any) -> bool:
    return isinstance(t, type) and issubclass(t, BaseModel)


def _strip(t: Any, meta: list) -> Any:
    """``t`` without Annotated and Optional, its metadata appended to ``meta``."""
    while True:
        if get_origin(t) is Annotated:
            args = get_args(t)
            meta.extend(args[1:])
            t = args[0]
        elif get_origin(t) is Union and type(None) in get_args(t):
            rest = [a for a in get_args(t) if a is not type(None)]
            t = rest[0] if len(rest) == 1 else Union[tuple(rest)]
        else:
            return t


def _annotation_at(loc: tuple) -> tuple[Any, list]:
    """The type at ``loc`` below :class:`RunConfig` and its metadata (outermost first)."""
    t, meta = RunConfig, []
    for part in loc:
        meta = []
        t = _strip(t, meta)
        if _is_model(t) and isinstance(part, str):
            field = next((f for k, f in t.model_fields.items() if part in (k, f.alias)), None)
            if field is None:
                raise KeyError(f"{format_path(loc)}: no such key in the schema")
            meta = list(field.metadata)
            t = field.annotation
        elif get_origin(t) is list and isinstance(part, int):
            t = get_args(t)[0]
        elif get_origin(t) is dict:
            t = get_args(t)[1]
        else:
            raise KeyError(f"{format_path(loc)}: no such key in the schema")
    t = _strip(t, meta)
    return t, meta


def rule_for(path: str) -> Rule | None:
    """The :class:`Rule` of the leaf at ``path`` (``world.skills.move.x[0]``), or None (a group)."""
    _, meta = _annotation_at(split_path(path))
    return next((m for m in meta if isinstance(m, Rule)), None)
