"""Configuration of the learned dynamics model: data generation, network, training, evaluation.

The dataclass defaults are the single source of truth; ``configs/dynamics/default.yaml`` mirrors
them (a test keeps the two in sync) so that Hydra can override any field on the command line.
The dataclasses do not read the YAML themselves because ``configs/`` is not shipped inside an
installed package.

Caching: a dataset is identified by :func:`data_hash` (a digest of the data-generation fields and the
*content* of the world config, so that editing the world geometry regenerates the data; of the world,
only what reaches the source data, :func:`source_world`); a checkpoint by :func:`model_hash` (the data
hash plus the model and training fields). Evaluation, benchmark and cache-location fields are in
neither hash.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping

import yaml

from sim.engine.config import NUMERICS_REVISION
from sim.world import DEFAULT_CONFIG, WorldConfig

#: bump when the dataset layout, the generator's semantics or what :func:`data_hash` covers change (a cached or
#: shipped dataset of another version is refused, and the message says how to make it again)
DATA_FORMAT_VERSION = 2
#: bump when the network / checkpoint layout or what :func:`model_hash` covers change (the same for checkpoints)
MODEL_FORMAT_VERSION = 3

TRAIN_COMMAND = "python -m dynamics.train"
ACTIVATIONS = ("silu", "tanh", "relu")


class DynamicsError(ValueError):
    """Bad dynamics config, dataset, checkpoint or model input; the message says how to fix it."""


def _range(name: str, r: Any, lo_limit: float | None = None, hi_limit: float | None = None) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in r)
    except (TypeError, ValueError):
        raise DynamicsError(f"{name} must be a pair [low, high], got {r!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
        raise DynamicsError(f"{name} = [{lo}, {hi}]: allowed a finite range with low <= high")
    if lo_limit is not None and lo < lo_limit:
        raise DynamicsError(f"{name} = [{lo}, {hi}]: low end below {lo_limit}")
    if hi_limit is not None and hi > hi_limit:
        raise DynamicsError(f"{name} = [{lo}, {hi}]: high end above {hi_limit}")
    return (lo, hi)


def _prob(name: str, v: Any) -> float:
    v = float(v)
    if not 0.0 <= v <= 1.0:
        raise DynamicsError(f"{name} = {v}: allowed a probability in [0, 1]")
    return v


def _int(name: str, v: Any, lo: int, hi: int | None = None) -> int:
    if isinstance(v, bool) or int(v) != float(v):
        raise DynamicsError(f"{name} = {v!r}: allowed an integer")
    v = int(v)
    if v < lo or (hi is not None and v > hi):
        raise DynamicsError(f"{name} = {v}: allowed {lo}..{hi if hi is not None else 'inf'}")
    return v


@dataclass(frozen=True)
class DataConfig:
    """Source-world data generation (random action sequences executed in batched simulators).

    Starts: with probability ``p_problem_start`` from the planning problems' start region, else
    uniform over the whole move range (collision-free, ``start_margin`` from any obstacle). Each
    trajectory has ``min_actions..max_actions`` actions, cut so that its schedule lasts at most
    ``max_sim_seconds`` (every environment of a batch is simulated as long as its longest one, so
    this keeps batches balanced). A move goes "near the target cup" with ``p_near_target``: its
    target is ``target_cup.x + near_target_dx`` at height ``near_target_y`` (clipped to the move
    range), and is followed by a pour with ``p_pour_after_near``; otherwise the next action is a
    pour with ``p_pour`` (``p_pour_after_pour`` right after a pour, since a second pour often
    starts from an empty cup). A pour's angle is drawn from ``pour_theta_focus`` (where water
    actually leaves a full or partly full cup) with ``p_theta_focus``, else from the whole skill
    range. Sequences whose (precomputed, kinematic) schedule gets stuck on an
    obstacle are kept with probability ``p_keep_stuck`` (``p_keep_stuck_pour`` when the stuck
    action is a pour, which is rarer and more informative: the cup stays tilted and keeps its
    water) and otherwise resampled, so that stuck transitions are covered without most
    trajectories ending after one or two actions.

    Focused pours (``pour_batches`` > 0): that many more batches of trajectories made for
    the pours plans use: from a start drawn as above, a move to a lattice point in ``pour_x`` x ``pour_y``
    (next to the target cup), a pour of the full cup with an angle in ``pour_theta`` (the steep part of its
    outcome curve), and with ``p_second_pour`` a second, steeper pour. Random sequences put few full-cup
    pours there (59 of 5,976 transitions in the random data), where a plan's partial pour is decided;
    with them the held-out first pours' labels fall under d_max at mean + 2 std (BENCHMARKS.md, dynamics
    model accuracy).
    """

    seed: int = 0
    n_batches: int = 48
    batch_size: int = 32
    min_actions: int = 4
    max_actions: int = 6
    max_sim_seconds: float = 14.0
    p_problem_start: float = 0.5
    p_pour: float = 0.4
    p_pour_after_pour: float = 0.2
    p_near_target: float = 0.5
    p_pour_after_near: float = 0.8
    pour_theta_focus: tuple[float, float] = (0.9, 2.2)
    p_theta_focus: float = 0.7
    near_target_dx: tuple[float, float] = (-0.02, 0.22)
    near_target_y: tuple[float, float] = (0.13, 0.34)
    p_keep_stuck: float = 0.35
    p_keep_stuck_pour: float = 1.0
    start_margin: float = 0.005
    pour_batches: int = 24
    pour_x: tuple[float, float] = (0.28, 0.35)
    pour_y: tuple[float, float] = (0.10, 0.30)
    pour_theta: tuple[float, float] = (0.9, 1.6)
    p_second_pour: float = 0.5
    #: world YAML (None: sim's configs/world/default.yaml); its content is part of the data hash
    world: str | None = None

    def __post_init__(self) -> None:
        s = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731  (frozen dataclass)
        s("seed", _int("data.seed", self.seed, 0))
        s("n_batches", _int("data.n_batches", self.n_batches, 1))
        s("batch_size", _int("data.batch_size", self.batch_size, 1))
        s("min_actions", _int("data.min_actions", self.min_actions, 1, 6))
        s("max_actions", _int("data.max_actions", self.max_actions, self.min_actions, 6))
        if not float(self.max_sim_seconds) > 0:
            raise DynamicsError(f"data.max_sim_seconds = {self.max_sim_seconds}: allowed > 0 s")
        s("max_sim_seconds", float(self.max_sim_seconds))
        for k in (
            "p_problem_start",
            "p_pour",
            "p_pour_after_pour",
            "p_near_target",
            "p_pour_after_near",
            "p_theta_focus",
            "p_keep_stuck",
            "p_keep_stuck_pour",
        ):
            s(k, _prob(f"data.{k}", getattr(self, k)))
        s("near_target_dx", _range("data.near_target_dx", self.near_target_dx))
        s("near_target_y", _range("data.near_target_y", self.near_target_y))
        s("pour_theta_focus", _range("data.pour_theta_focus", self.pour_theta_focus))
        if not float(self.start_margin) >= 0:
            raise DynamicsError(f"data.start_margin = {self.start_margin}: allowed >= 0 m")
        s("start_margin", float(self.start_margin))
        s("pour_batches", _int("data.pour_batches", self.pour_batches, 0))
        for k in ("pour_x", "pour_y", "pour_theta"):
            s(k, _range(f"data.{k}", getattr(self, k)))
        s("p_second_pour", _prob("data.p_second_pour", self.p_second_pour))


@dataclass(frozen=True)
class ModelConfig:
    """One MLP per skill; see :class:`dynamics.model.LearnedDynamics` for the output structure.

    ``ensemble`` > 1: the model is the mean of that many such models (:class:`dynamics.ensemble.
    DynamicsEnsemble`), each trained on its own trajectory split and initialisation; a planner
    searching a single model finds its idiosyncratic errors, the mean has fewer of them.
    """

    hidden: tuple[int, ...] = (128, 128, 128)
    activation: str = "silu"
    #: floors of the output scales (pose residual in m / rad, water fractions), so that a
    #: component that never changes in the data does not get an infinite loss weight
    min_pose_scale: float = 0.002
    min_fraction_scale: float = 0.01
    ensemble: int = 3

    def __post_init__(self) -> None:
        h = tuple(_int("model.hidden[]", v, 1) for v in self.hidden)
        if not h:
            raise DynamicsError("model.hidden = []: allowed a non-empty list of layer widths")
        object.__setattr__(self, "hidden", h)
        if self.activation not in ACTIVATIONS:
            raise DynamicsError(f"model.activation = {self.activation!r}: allowed one of {ACTIVATIONS}")
        for k in ("min_pose_scale", "min_fraction_scale"):
            if not float(getattr(self, k)) > 0:
                raise DynamicsError(f"model.{k} = {getattr(self, k)}: allowed > 0")
            object.__setattr__(self, k, float(getattr(self, k)))
        object.__setattr__(self, "ensemble", _int("model.ensemble", self.ensemble, 1))


LOSSES = ("distance", "scaled_mse")
LR_SCHEDULES = ("constant", "cosine")


@dataclass(frozen=True)
class TrainConfig:
    """Adam, split by trajectory, early stopping on the validation loss.

    ``loss``: ``distance`` minimises the mean state distance d(f_hat(s, a), s') with the world's
    distance weights, i.e. exactly the MDE's label, and being L1-like it is robust to the rare
    stuck pours; ``scaled_mse`` is the squared error in per-skill output units (sensitive to those
    rare events: a residual that is almost always zero gets a tiny scale).

    ``lr_schedule``: ``constant`` keeps ``lr``; ``cosine`` anneals it to 0 over ``max_epochs``
    (``torch.optim.lr_scheduler.CosineAnnealingLR``), so the last epochs settle into a minimum
    instead of bouncing around it at the full step size.
    """

    seed: int = 0
    loss: str = "distance"
    val_fraction: float = 0.15
    max_epochs: int = 300
    batch_size: int = 256
    lr: float = 4.0e-3
    weight_decay: float = 1.0e-5
    patience: int = 200
    lr_schedule: str = "cosine"
    #: torch intra-op threads while training (restored afterwards; :func:`task.threads.torch_threads`); at least 1:
    #: a fixed count keeps training bit-reproducible
    threads: int = 1

    def __post_init__(self) -> None:
        s = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        s("seed", _int("train.seed", self.seed, 0))
        if self.loss not in LOSSES:
            raise DynamicsError(f"train.loss = {self.loss!r}: allowed one of {LOSSES}")
        if self.lr_schedule not in LR_SCHEDULES:
            raise DynamicsError(f"train.lr_schedule = {self.lr_schedule!r}: allowed one of {LR_SCHEDULES}")
        if not 0.0 < float(self.val_fraction) < 1.0:
            raise DynamicsError(f"train.val_fraction = {self.val_fraction}: allowed (0, 1)")
        s("val_fraction", float(self.val_fraction))
        s("max_epochs", _int("train.max_epochs", self.max_epochs, 1))
        s("batch_size", _int("train.batch_size", self.batch_size, 1))
        s("patience", _int("train.patience", self.patience, 1))
        s("threads", _int("train.threads", self.threads, 1))
        if not float(self.lr) > 0:
            raise DynamicsError(f"train.lr = {self.lr}: allowed > 0")
        if not float(self.weight_decay) >= 0:
            raise DynamicsError(f"train.weight_decay = {self.weight_decay}: allowed >= 0")
        s("lr", float(self.lr))
        s("weight_decay", float(self.weight_decay))


@dataclass(frozen=True)
class EvalConfig:
    """``python -m dynamics.evaluate``: fresh source-world test data and target-world data.

    A target-world transition is *near the plant* when the plant (at that problem's pose) comes
    within ``near_radius`` of the controlled cup's outline anywhere along the action's executed
    path, or, for a pour, of the water's fall region (between the vertical below the pouring lip
    and the ballistic path of water leaving the lip towards the target at ``stream_speed``);
    otherwise it is *far*. ``stream_speed`` = 0.6 m/s matches where fully poured water lands in
    the source-world data (e.g. ~40% still reaches the target cup from a lip 0.1 m right of it
    and 0.14-0.22 m above its rim).
    """

    seed: int = 1000
    source_batches: int = 2
    target_batches: int = 3
    near_radius: float = 0.03
    stream_speed: float = 0.6

    def __post_init__(self) -> None:
        object.__setattr__(self, "seed", _int("eval.seed", self.seed, 0))
        object.__setattr__(self, "source_batches", _int("eval.source_batches", self.source_batches, 0))
        object.__setattr__(self, "target_batches", _int("eval.target_batches", self.target_batches, 0))
        if not float(self.near_radius) >= 0:
            raise DynamicsError(f"eval.near_radius = {self.near_radius}: allowed >= 0 m")
        object.__setattr__(self, "near_radius", float(self.near_radius))
        if not float(self.stream_speed) >= 0:
            raise DynamicsError(f"eval.stream_speed = {self.stream_speed}: allowed >= 0 m/s")
        object.__setattr__(self, "stream_speed", float(self.stream_speed))


@dataclass(frozen=True)
class DynamicsConfig:
    """Everything ``python -m dynamics.train`` / :func:`dynamics.load_or_train` needs."""

    #: datasets and checkpoints live under ``<cache_root>/data-<hash>/`` and ``model-<hash>/``;
    #: a relative path is relative to the current working directory
    cache_root: str = ".cache/dynamics"
    #: show tqdm progress bars
    progress: bool = True
    data: DataConfig = field(default_factory=DataConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)

    def __post_init__(self) -> None:
        for name, cls in (("data", DataConfig), ("model", ModelConfig), ("train", TrainConfig), ("eval", EvalConfig)):
            v = getattr(self, name)
            if isinstance(v, Mapping):
                object.__setattr__(self, name, cls(**_known(cls, v, f"dynamics.{name}")))
            elif not isinstance(v, cls):
                raise DynamicsError(f"dynamics.{name}: expected a mapping, got {type(v).__name__}")
        object.__setattr__(self, "cache_root", str(self.cache_root))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None = None, **overrides: Any) -> "DynamicsConfig":
        """Build from a plain or OmegaConf mapping (missing keys take defaults; unknown keys error)."""
        data: dict[str, Any] = dict(_to_plain(d) or {})
        data.update(overrides)
        data.pop("hydra", None)
        return cls(**_known(cls, data, "dynamics config"))

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict with lists (the YAML layout)."""
        return _plain(self)

    def replace(self, **changes: Any) -> "DynamicsConfig":
        return dataclasses.replace(self, **changes)


# ---------------------------------------------------------------------------------- hashing
def world_config(data: DataConfig, world_cfg: Any = None) -> WorldConfig:
    """The world the data is generated in: ``world_cfg`` (a ``sim.world.WorldConfig``, or a plain / OmegaConf
    mapping of the world YAML's fields, e.g. the main job's ``cfg.world``) if given, else the ``data.world``
    file (default: ``sim``'s ``configs/world/default.yaml``), so a world changed on the experiment's command
    line reaches the data generator and its hash."""
    if isinstance(world_cfg, WorldConfig):
        return world_cfg
    if world_cfg is None:
        path = Path(data.world) if data.world else DEFAULT_CONFIG
        if not path.is_file():
            raise DynamicsError(f"data.world = {data.world!r}: no such world config file ({path})")
        what, world_cfg = str(path), yaml.safe_load(path.read_text())
    else:
        what = "world config"
    try:
        return WorldConfig.from_mapping(_to_plain(world_cfg))
    except (ValueError, TypeError, KeyError) as e:
        raise DynamicsError(f"{what} is not a valid world config: {e}") from None


def world_dict(data: DataConfig, world_cfg: Any = None) -> dict[str, Any]:
    """The world config the data is generated with (:func:`world_config`) as a canonical plain mapping
    (defaults filled in), so equal worlds hash equally however they were given."""
    return json.loads(json.dumps(dataclasses.asdict(world_config(data, world_cfg)), default=_plain))


def source_world(data: DataConfig, world_cfg: Any = None) -> dict[str, Any]:
    """What a source-world dataset depends on of its world: the world config (:func:`world_dict`) with every
    solver setting, the solver's defaults filled in (so that a changed physics default makes new data), less
    what does not reach the data:

    * the plant: the source world has none (``WorldConfig.obstacle_bodies``), so a changed plant (the target
      world's deviation) keeps the source data; what holds target-world data keys on :func:`plant_dict` too;
    * the goal range (``problems.goal``): the generator draws starts and actions, never a goal (goals only pose
      planning problems), so a world that poses other goals keeps its data;
    * where the solver runs (``sim.arch``): CPU and GPU make the same data within ``benchmarks.check_arch``'s
      tolerances, and a GPU run uses the CPU-made shipped data instead of simulating it again;
    * ``sim.n_envs``: how many environments one solver call runs at once, which ``data.batch_size`` sets;

    plus the solver's arithmetic (``sim.engine.config.NUMERICS_REVISION``), which rounds every pour.
    """
    world = world_config(data, world_cfg)
    out = world_dict(data, world)
    out.pop("plant")
    out["problems"].pop("goal")
    solver = dataclasses.asdict(world.sim_config(1))
    for k in ("arch", "n_envs"):
        solver.pop(k)
    out["sim"] = json.loads(json.dumps(solver, default=_plain))
    out["sim"]["numerics_revision"] = NUMERICS_REVISION
    return out


def _digest(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()).hexdigest()[:16]


def data_hash(cfg: DynamicsConfig, world_cfg: Any = None) -> str:
    """Identity of a source-world dataset: a digest of the format version, every generator field (``data.world``
    as its content, :func:`source_world`, not its path)."""
    d = _plain(cfg.data)
    d.pop("world")
    return _digest({"format": DATA_FORMAT_VERSION, "data": d, "world": source_world(cfg.data, world_cfg)})


#: the data fields of the focused pours (:class:`DataConfig`): the random sequences' batches do not depend on them
POUR_FIELDS = ("pour_batches", "pour_x", "pour_y", "pour_theta", "p_second_pour")


def plant_dict(data: DataConfig, world_cfg: Any = None) -> dict[str, Any]:
    """The plant of that world (the part of the world :func:`data_hash` leaves out)."""
    return world_dict(data, world_cfg)["plant"]


def model_hash(cfg: DynamicsConfig, dhash: str | None = None, world_cfg: Any = None) -> str:
    """Identity of a checkpoint: a digest of the format version, the dataset's identity and every model and
    training field."""
    return _digest(
        {
            "format": MODEL_FORMAT_VERSION,
            "data": dhash or data_hash(cfg, world_cfg),
            "model": _plain(cfg.model),
            "train": _plain(cfg.train),
        }
    )


def ensemble_member(cfg: DynamicsConfig, k: int) -> DynamicsConfig:
    """The config of member ``k`` of ``cfg``'s ensemble: a single model trained with seed
    ``train.seed * ensemble + k``, so that the ensembles of different seeds share no member and
    every member is cached (and reused) as a model of its own."""
    n = cfg.model.ensemble
    if not 0 <= k < n:
        raise DynamicsError(f"ensemble member {k}: allowed 0..{n - 1} (model.ensemble = {n})")
    return dataclasses.replace(
        cfg,
        model=dataclasses.replace(cfg.model, ensemble=1),
        train=dataclasses.replace(cfg.train, seed=cfg.train.seed * n + k),
    )


def single_models(cfg: DynamicsConfig) -> list[DynamicsConfig]:
    """The single models ``cfg`` is made of, each cached as a model of its own: its ensemble's members,
    or ``cfg`` itself when it is one model."""
    return [ensemble_member(cfg, k) for k in range(cfg.model.ensemble)] if cfg.model.ensemble > 1 else [cfg]


# ---------------------------------------------------------------------------------- helpers
def _known(cls: type, data: Mapping[str, Any], what: str) -> dict[str, Any]:
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise DynamicsError(f"unknown {what} key(s) {unknown}; allowed: {sorted(names)}")
    return dict(data)


def _plain(v: Any) -> Any:
    if dataclasses.is_dataclass(v):
        return {f.name: _plain(getattr(v, f.name)) for f in fields(v)}
    if isinstance(v, (tuple, list)):
        return [_plain(x) for x in v]
    if isinstance(v, Mapping):
        return {k: _plain(x) for k, x in v.items()}
    return v


def _to_plain(d: Any) -> Any:
    if d is None:
        return None
    # imported here: planner worker processes load this module with the model they unpickle and never see a
    # Hydra node, so they need not import omegaconf
    from omegaconf import DictConfig, ListConfig, OmegaConf

    if isinstance(d, (DictConfig, ListConfig)):
        return OmegaConf.to_container(d, resolve=True)
    return d
