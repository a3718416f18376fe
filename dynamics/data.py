"""Transition datasets (s, a, s') of the pouring worlds: container, file format, generator.

The dynamics model is trained on source-world data only (the paper's cheap simulator without the
plant); :func:`generate_transitions` with ``world="target"`` produces the small target-world sets
used to show where the model deviates. Generation runs B trajectories per batched simulator call
(one :class:`sim.execute.PouringExecutor`, one fixed B, so the compiled solver is reused), writes
every finished batch as a shard so that an interrupted run resumes, and drops trajectories whose
environment went numerically unstable.

File format (``torch.save`` of plain tensors, loadable with ``weights_only=True``): a dict with
``format``, ``version``, ``arrays`` (name -> tensor) and ``meta`` (a JSON string: config, seed,
counts, wall time). Writes are atomic and fsync-ed (:mod:`safeio`).
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

import safeio
from sim.engine.scene import Body
from sim.skills import Obstacles, cup_boundary, plan_schedule
from task import ACTION_DIM, STATE_DIM, check_world, sample_problems
from task import SKILL_MOVE as MOVE
from task import SKILL_POUR as POUR

from .config import (
    DATA_FORMAT_VERSION,
    POUR_FIELDS,
    TRAIN_COMMAND,
    DataConfig,
    DynamicsError,
    _digest,
    _plain,
    plant_dict,
    source_world,
    world_config,
)

log = logging.getLogger(__name__)

DATASET_FORMAT = "active-mde/dynamics-dataset"
#: arrays of a dataset: name -> (trailing shape, dtype)
FIELDS: dict[str, tuple[tuple[int, ...], Any]] = {
    "s": ((STATE_DIM,), np.float32),
    "a": ((ACTION_DIM,), np.float32),
    "s_next": ((STATE_DIM,), np.float32),
    "traj": ((), np.int64),  # trajectory id (the train/validation split is by trajectory)
    "step": ((), np.int64),  # index of the action within its trajectory
    "stuck": ((), np.bool_),  # the cup hit an obstacle during this action
    "plant_jitter": ((3,), np.float32),  # plant pose offset of the problem (zeros in the source world)
}
_FRACTION_TOL = 1e-3


@dataclass
class Transitions:
    """A set of (s, a, s') transitions with their provenance; arrays share the first axis."""

    s: np.ndarray
    a: np.ndarray
    s_next: np.ndarray
    traj: np.ndarray
    step: np.ndarray
    stuck: np.ndarray
    plant_jitter: np.ndarray
    meta: dict = field(default_factory=dict)

    @classmethod
    def from_arrays(
        cls,
        s: Any,
        a: Any,
        s_next: Any,
        traj: Any = None,
        step: Any = None,
        stuck: Any = None,
        plant_jitter: Any = None,
        meta: dict | None = None,
    ) -> "Transitions":
        """Build (and validate) from array-likes; provenance fields default to one-step trajectories."""
        s = np.asarray(s, np.float32)
        n = len(s) if s.ndim >= 1 else 0
        arr = {
            "s": s,
            "a": a,
            "s_next": s_next,
            "traj": np.arange(n) if traj is None else traj,
            "step": np.zeros(n) if step is None else step,
            "stuck": np.zeros(n, bool) if stuck is None else stuck,
            "plant_jitter": np.zeros((n, 3)) if plant_jitter is None else plant_jitter,
        }
        arr = {k: np.asarray(v).astype(FIELDS[k][1], copy=False) for k, v in arr.items()}
        out = cls(**arr, meta=dict(meta or {}))
        out.validate()
        return out

    def __len__(self) -> int:
        return len(self.s)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in FIELDS}

    def subset(self, idx: np.ndarray) -> "Transitions":
        return Transitions(**{k: v[idx] for k, v in self.arrays().items()}, meta=dict(self.meta))

    @staticmethod
    def concat(parts: list["Transitions"], meta: dict | None = None) -> "Transitions":
        if not parts:
            return Transitions.from_arrays(np.zeros((0, 5)), np.zeros((0, 3)), np.zeros((0, 5)), meta=meta)
        arr = {k: np.concatenate([getattr(p, k) for p in parts]) for k in FIELDS}
        return Transitions(**arr, meta=dict(meta or {}))

    def skill(self) -> np.ndarray:
        return np.rint(self.a[:, 0]).astype(np.int64)

    def validate(self, what: str = "dataset") -> None:
        """Shapes, finiteness, skill ids and water fractions; raises :class:`DynamicsError`."""
        n = len(self.s) if np.ndim(self.s) >= 1 else -1
        for k, (shape, _) in FIELDS.items():
            v = getattr(self, k)
            if v.shape != (n,) + shape:
                raise DynamicsError(
                    f"{what}: array {k!r} has shape {v.shape}, expected {(max(n, 0),) + shape} "
                    f"(states are (x, y, theta, v_ctrl, v_tgt), actions (skill_id, p1, p2))"
                )
        for k in ("s", "a", "s_next", "plant_jitter"):
            if not np.isfinite(getattr(self, k)).all():
                raise DynamicsError(f"{what}: array {k!r} contains NaN or inf")
        sk = self.a[:, 0]
        bad = (np.abs(sk - np.rint(sk)) > 1e-4) | ~np.isin(np.rint(sk), (MOVE, POUR))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise DynamicsError(f"{what}: action {i} has skill id {sk[i]:g}; allowed 0 (move) or 1 (pour)")
        for k in ("s", "s_next"):
            v = getattr(self, k)[:, 3:5]
            if len(v) and ((v < -_FRACTION_TOL).any() or (v.sum(1) > 1 + _FRACTION_TOL).any()):
                raise DynamicsError(f"{what}: {k!r} has water fractions outside [0, 1] or v_ctrl + v_tgt > 1")

    # ------------------------------------------------------------------ files
    def save(self, path: str | Path) -> Path:
        """Atomic write (:mod:`safeio`: temporary file in the same folder, fsync, ``os.replace``)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        payload = {
            "format": DATASET_FORMAT,
            "version": DATA_FORMAT_VERSION,
            "arrays": {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in self.arrays().items()},
            "meta": json.dumps(self.meta, default=safeio.json_default),
        }
        atomic_torch_save(payload, path)
        return path

    @classmethod
    def load(cls, path: str | Path, expected_hash: str | None = None) -> "Transitions":
        """Load and validate; errors say what is wrong and how to regenerate."""
        path = Path(path)
        payload, fix = load_tagged(path, "dataset", DATASET_FORMAT, DATA_FORMAT_VERSION, "regenerate it", "generate")
        try:
            arrays = {k: payload["arrays"][k].numpy() for k in FIELDS}
            meta = json.loads(payload["meta"])
        except (KeyError, TypeError, AttributeError, json.JSONDecodeError) as e:
            raise DynamicsError(f"dynamics dataset {path} is incomplete ({type(e).__name__}: {e}); {fix}") from None
        out = cls(**arrays, meta=meta)
        out.validate(what=f"dynamics dataset {path}")
        if expected_hash is not None and meta.get("data_hash") != expected_hash:
            raise DynamicsError(
                f"dynamics dataset {path} was generated by another data config (hash "
                f"{meta.get('data_hash')}, expected {expected_hash}); {fix}"
            )
        return out

    def summary(self) -> dict[str, Any]:
        sk = self.skill()
        return {
            "transitions": len(self),
            "trajectories": int(len(np.unique(self.traj))),
            "move": int((sk == MOVE).sum()),
            "pour": int((sk == POUR).sum()),
            "stuck": int(self.stuck.sum()),
        }


def load_tagged(path: Path, what: str, fmt: str, version: int, redo: str, do: str) -> tuple[dict, str]:
    """Read a torch file written with a format tag and version; errors say how to regenerate it.

    Returns the payload and the "how to fix" text for the caller's own content checks."""
    fix = f"delete {path} and {redo} with `{TRAIN_COMMAND}` (same config overrides)"
    if not path.is_file():
        raise DynamicsError(f"dynamics {what} {path} does not exist; {do} it with `{TRAIN_COMMAND}`")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unpickling failure means a corrupt file
        raise DynamicsError(
            f"dynamics {what} {path} is corrupt or not a torch file ({type(e).__name__}: {str(e)[:200]}); {fix}"
        ) from None
    if not isinstance(payload, dict) or payload.get("format") != fmt:
        raise DynamicsError(f"{path} is not a dynamics {what} (format tag missing); {fix}")
    if payload.get("version") != version:
        raise DynamicsError(
            f"dynamics {what} {path} has format version {payload.get('version')}, this code "
            f"reads version {version}; {fix}"
        )
    return payload, fix


def atomic_torch_save(obj: Any, path: Path) -> None:
    """Atomic, fsync-ed ``torch.save`` with the umask's permissions (the project's one writer, :mod:`safeio`)."""
    safeio.save_torch(path, obj)


# ---------------------------------------------------------------------------------- sampling
class SequenceSampler:
    """Random start poses and action sequences covering the states the planner will ask about.

    See :class:`dynamics.config.DataConfig` for the distribution. The schedule pre-check uses the
    simulator's own kinematic planner (``sim.skills.plan_schedule``) on a coarse cup outline, so
    it predicts durations exactly and contact approximately (it only decides what to resample).
    """

    def __init__(self, data: DataConfig, wcfg: Any):
        self.data = data
        self.wcfg = wcfg
        self.move_x = tuple(wcfg.skills["move"]["x"])
        self.move_y = tuple(wcfg.skills["move"]["y"])
        self.theta = tuple(wcfg.skills["pour"]["theta"])
        self.hold = tuple(wcfg.skills["pour"]["hold"])
        self.boundary = cup_boundary(wcfg, spacing=0.01)
        self.interior_lo = np.full(2, wcfg.floor)
        self.interior_hi = np.asarray(wcfg.sim["domain"], float) - wcfg.floor

    def obstacles(self, world: str, jitter: np.ndarray) -> Any:
        return Obstacles(self.wcfg.obstacle_bodies(world, jitter), self.interior_lo, self.interior_hi)

    def start(self, rng: np.random.Generator, obstacles: Any) -> np.ndarray:
        """Upright collision-free start position (x, y)."""
        pr = self.wcfg.problems
        for _ in range(1000):
            if rng.random() < self.data.p_problem_start:
                p = np.array([rng.uniform(*pr["start_x"]), rng.uniform(*pr["start_y"])])
            else:
                p = np.array([rng.uniform(*self.move_x), rng.uniform(*self.move_y)])
            d, _ = obstacles.sdf(self.boundary + p)
            if d.min() >= self.data.start_margin:
                return p
        raise DynamicsError(
            "could not sample a collision-free start pose in 1000 tries: check data.start_margin "
            "and the world's move / start ranges"
        )

    def actions(self, rng: np.random.Generator, n: int) -> np.ndarray:
        d, tx = self.data, self.wcfg.target_cup.x
        out = np.empty((n, 3))
        prev = None  # "near" (a move near the target cup), "pour", or None
        focus = (max(d.pour_theta_focus[0], self.theta[0]), min(d.pour_theta_focus[1], self.theta[1]))
        for t in range(n):
            p_pour = {"near": d.p_pour_after_near, "pour": d.p_pour_after_pour}.get(prev, d.p_pour)
            if rng.random() < p_pour:
                theta = (
                    rng.uniform(*focus)
                    if focus[0] < focus[1] and rng.random() < d.p_theta_focus
                    else rng.uniform(*self.theta)
                )
                out[t] = (POUR, theta, rng.uniform(*self.hold))
                prev = "pour"
            elif rng.random() < d.p_near_target:
                x = float(np.clip(tx + rng.uniform(*d.near_target_dx), *self.move_x))
                y = float(np.clip(rng.uniform(*d.near_target_y), *self.move_y))
                out[t] = (MOVE, x, y)
                prev = "near"
            else:
                out[t] = (MOVE, rng.uniform(*self.move_x), rng.uniform(*self.move_y))
                prev = None
        return out

    def focused_pour(self, rng: np.random.Generator, world: str, jitter: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One focused-pour sequence (start (2,), actions): a move next to the target cup (``pour_x`` x ``pour_y``,
        put on the lattice by the executor), a pour of the full cup at an angle in ``pour_theta`` and, with
        ``p_second_pour``, a second pour up to 0.4 rad steeper (what a plan's partial pour is followed by)."""
        d = self.data
        start = self.start(rng, self.obstacles(world, jitter))
        x, y, theta = rng.uniform(*d.pour_x), rng.uniform(*d.pour_y), rng.uniform(*d.pour_theta)
        acts = [(MOVE, x, y), (POUR, theta, rng.uniform(*self.hold))]
        if rng.random() < d.p_second_pour:
            acts.append((POUR, min(theta + rng.uniform(0.0, 0.4), self.theta[1]), rng.uniform(*self.hold)))
        return start, np.array(acts, float)

    def sample(
        self, rng: np.random.Generator, world: str, jitter: np.ndarray, keep_all_stuck: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """One (start (2,), actions (T, 3)) pair, cut to ``max_sim_seconds``; stuck ones mostly resampled."""
        obst = self.obstacles(world, jitter)
        h = self.wcfg.control_dt
        for _ in range(100):
            start = self.start(rng, obst)
            acts = self.actions(rng, int(rng.integers(self.data.min_actions, self.data.max_actions + 1)))
            sched = plan_schedule(self.wcfg, np.array([start[0], start[1], 0.0]), acts, obst, self.boundary)
            ends = np.asarray(sched.action_end) * h
            n_fit = max(1, int(np.sum(ends <= self.data.max_sim_seconds)))  # actions within the time budget
            stuck_in_prefix = any(i < n_fit for i in sched.blocked)
            acts = acts[: min(n_fit, sched.executed)]
            if not stuck_in_prefix or keep_all_stuck:
                return start, acts
            keep = self.data.p_keep_stuck_pour if int(acts[-1, 0]) == POUR else self.data.p_keep_stuck
            if rng.random() < keep:
                return start, acts
        return start, acts


# ---------------------------------------------------------------------------------- generation
def generate_transitions(
    data: DataConfig,
    world: str = "source",
    n_batches: int | None = None,
    seed: int | None = None,
    keep_all_stuck: bool = False,
    progress: bool = True,
    shard_dir: str | Path | None = None,
    meta: dict | None = None,
    executor: Any = None,
    world_cfg: Any = None,
    pours: bool = False,
) -> Transitions:
    """Execute random sequences in ``world`` (batched) and return their transitions.

    ``pours``: the focused-pour batches instead (:meth:`SequenceSampler.focused_pour`; ``n_batches`` defaults
    to ``data.pour_batches``, own random streams and shard files, trajectory indices after the random ones').

    ``n_batches`` / ``seed`` default to ``data``'s; ``keep_all_stuck`` ignores the ``p_keep_stuck*``
    resampling (the natural distribution, for evaluation sets). Batch ``b`` draws from
    ``np.random.default_rng([seed, b, world])``, so a batch's content does not depend on the others;
    with ``shard_dir`` every finished batch is saved there and reused on the next call (resume).
    In the target world the plant pose of every trajectory is drawn like a planning problem's.
    ``world_cfg`` (WorldConfig or mapping) replaces the ``data.world`` file (see
    :func:`dynamics.config.world_config`).
    """
    from sim.execute import PouringExecutor  # Taichi: loaded only to simulate, not by `import dynamics`

    check_world(world)
    n_batches = (data.pour_batches if pours else data.n_batches) if n_batches is None else int(n_batches)
    seed = data.seed if seed is None else int(seed)
    wcfg = world_config(data, world_cfg)
    sampler = SequenceSampler(data, wcfg)
    B = data.batch_size
    ex = executor or PouringExecutor(wcfg)
    shard_dir = Path(shard_dir) if shard_dir else None
    parts: list[Transitions] = []
    counts = {"trajectories": 0, "unstable": 0, "stuck": 0, "sim_seconds": 0.0, "categories": {}}
    t0 = time.perf_counter()
    world_code = 0 if world == "source" else 1
    what = "focused pours" if pours else f"{B} x <= {data.max_actions} actions"
    bar = tqdm(range(n_batches), desc=f"dynamics data ({world} world, {what})", unit="batch", disable=not progress)
    ident = shard_identity(data, wcfg, pours) if shard_dir else None
    first_traj = data.n_batches * B if pours else 0
    for b in bar:
        key = [seed, b, world, B, keep_all_stuck] + (["pours"] if pours else [])
        shard = shard_dir / f"{'pours' if pours else 'batch'}{b:04d}.pt" if shard_dir else None
        part = _saved_shard(shard, key, ident)
        if part is None:
            rng = np.random.default_rng([seed, b, world_code] + ([1] if pours else []))
            part = _simulate_batch(ex, sampler, wcfg, world, rng, B, keep_all_stuck, pours, first_traj + b * B)
            part.meta = {"shard_key": key, "config": ident, "counts": part.meta["counts"]}
            if shard is not None:
                part.save(shard)
        parts.append(part)
        _add_counts(counts, part.meta["counts"])
        bar.set_postfix(transitions=sum(len(p) for p in parts), unstable=counts["unstable"])
    bar.close()
    from sim.engine.backend import cpu_fingerprint  # Taichi, as above

    out = Transitions.concat(parts)
    out.meta = {
        **(meta or {}),
        "world": world,
        "seed": seed,
        "n_batches": n_batches,
        "batch_size": B,
        "focused_pours": pours,
        "counts": {**counts, **out.summary()},
        "wall_seconds": time.perf_counter() - t0,
        "data_config": _plain_data(data),
        "cpu": cpu_fingerprint(),
    }
    out.validate()
    return out


def _saved_shard(shard: Path | None, key: list, ident: str | None) -> Transitions | None:
    """The saved batch at ``shard`` if the same key and configuration made it, else None (it is simulated again)."""
    if shard is None or not shard.is_file():
        return None
    try:
        part = Transitions.load(shard)
        if part.meta.get("shard_key") == key and part.meta.get("config") == ident:
            return part
        log.warning("regenerating shard %s: another configuration made it", shard)
    except DynamicsError as e:
        log.warning("ignoring unreadable shard %s: %s", shard, e)
    return None


def _simulate_batch(
    ex: Any,
    sampler: Any,
    wcfg: Any,
    world: str,
    rng: np.random.Generator,
    B: int,
    keep_all_stuck: bool,
    pours: bool,
    traj_offset: int,
) -> Transitions:
    """One batch of B sequences (focused pours or random sequences) drawn from ``rng`` and executed in ``world``;
    its counts in ``meta["counts"]``. In the target world the plant poses are drawn like a planning problem's."""
    if world == "target":
        jit = np.array([p.plant_jitter for p in sample_problems(wcfg, B, int(rng.integers(2**31)), "target")])
    else:
        jit = np.zeros((B, 3))
    if pours:
        starts, seqs = zip(*(sampler.focused_pour(rng, world, jit[i]) for i in range(B)))
    else:
        starts, seqs = zip(*(sampler.sample(rng, world, jit[i], keep_all_stuck) for i in range(B)))
    results = ex.run(world, np.array(starts), list(seqs), plant_jitter=jit if world == "target" else None)
    part, c = _collect(results, jit, traj_offset=traj_offset)
    c["sim_seconds"] = float(ex.last_timing.get("sim_seconds", 0.0))
    part.meta = {"counts": c}
    return part


def shard_identity(data: DataConfig, wcfg: Any, pours: bool = False) -> str:
    """Digest of what a batch's content depends on besides its key: the generator fields (not the
    batch counts; the focused-pour fields only for a focused-pour batch) and the world, so a shard left
    by another configuration is never reused."""
    d = _plain_data(data)
    for k in ("world", "n_batches", "pour_batches") + (() if pours else POUR_FIELDS):
        d.pop(k, None)
    return _digest(
        {"format": DATA_FORMAT_VERSION, "data": d, "world": source_world(data, wcfg), "plant": plant_dict(data, wcfg)}
    )


def generate_source_dataset(
    cfg: Any, shard_dir: str | Path | None = None, progress: bool = True, world_cfg: Any = None
) -> Transitions:
    """The training data of the model: ``cfg.data`` sequences executed in the source world."""
    return generate_transitions(cfg.data, "source", shard_dir=shard_dir, progress=progress, world_cfg=world_cfg)


def _collect(results: list, jit: np.ndarray, traj_offset: int) -> tuple[Transitions, dict]:
    rows: dict[str, list] = {k: [] for k in FIELDS}
    c = {"trajectories": len(results), "unstable": 0, "stuck": 0, "categories": {}}
    for i, r in enumerate(results):
        c["categories"][r.category] = c["categories"].get(r.category, 0) + 1
        if r.unstable:
            c["unstable"] += 1
            continue
        c["stuck"] += int(r.stuck)
        for t, st in enumerate(r.steps):
            rows["s"].append(st.s)
            rows["a"].append(st.a)
            rows["s_next"].append(st.s_next)
            rows["traj"].append(traj_offset + i)
            rows["step"].append(t)
            rows["stuck"].append(bool(st.stuck))
            rows["plant_jitter"].append(jit[i])
    if not rows["s"]:
        return Transitions.concat([]), c
    return Transitions.from_arrays(**{k: np.asarray(v) for k, v in rows.items()}), c


def _add_counts(total: dict, c: dict) -> None:
    for k in ("trajectories", "unstable", "stuck", "sim_seconds"):
        total[k] = total.get(k, 0) + c.get(k, 0)
    for k, v in c.get("categories", {}).items():
        total["categories"][k] = total["categories"].get(k, 0) + v


def _plain_data(data: DataConfig) -> dict:
    return _plain(data)


# ---------------------------------------------------------------------------------- geometry
CLEARANCE_CAP = 0.1
GRAVITY = 9.81


def plant_clearance(wcfg: Any, tr: Transitions, world: str = "target", stream_speed: float = 0.6) -> np.ndarray:
    """Per transition: distance (m) from the plant to the cup's path or, for pours, the water's fall region.

    The cup's path is the action's executed kinematic schedule (``sim.skills.plan_schedule`` with
    the real obstacles, so a stuck action ends at its contact pose). Poured water leaves the
    pouring lip (the pivot, fixed during a pour) towards -x and falls; its fall region is taken
    as the area between the vertical below the lip and the ballistic path of water leaving the lip
    horizontally at ``stream_speed`` (m/s), x = x_lip - v sqrt(2 (y_lip - y) / g), down to the floor.
    Distances (resolution ~5 mm) are Euclidean to the plant's outline polygons (0 if a point lies inside),
    not the colliders' SDF, whose ellipse formula underestimates distances away from the surface.
    Values are capped at ``CLEARANCE_CAP`` (0.1 m: "at least that far").
    ``inf`` in the source world.
    """
    if world != "target":
        return np.full(len(tr), np.inf)
    boundary = cup_boundary(wcfg, spacing=0.01)
    lo, hi = np.full(2, wcfg.floor), np.asarray(wcfg.sim["domain"], float) - wcfg.floor
    lip = wcfg.controlled_cup.lip
    shapes = wcfg.plant_shapes()
    outline_local = np.concatenate([sh.outline(n=max(24, int(2 * np.pi * max(sh.size) / 0.002))) for sh in shapes])
    out = np.empty(len(tr))
    for i in range(len(tr)):
        jit = tr.plant_jitter[i]
        obst = Obstacles(wcfg.obstacle_bodies("target", jit), lo, hi)
        px, py, pth = wcfg.plant_pose(jit)
        c, sn = math.cos(pth), math.sin(pth)
        outline = outline_local @ np.array([[c, sn], [-sn, c]]) + np.array([px, py])
        s = tr.s[i].astype(float)
        sched = plan_schedule(wcfg, s[:3], tr.a[i : i + 1].astype(float), obst, boundary)
        poses = sched.poses[::3]  # <= ~7 mm apart at the skills' peak speeds
        cc, ss = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
        qx = cc * boundary[None, :, 0] - ss * boundary[None, :, 1] + poses[:, None, 0]
        qy = ss * boundary[None, :, 0] + cc * boundary[None, :, 1] + poses[:, None, 1]
        pts = [np.stack([qx, qy], -1).reshape(-1, 2)]
        if int(round(tr.a[i, 0])) == POUR:
            cth, sth = math.cos(s[2]), math.sin(s[2])
            pivot = s[:2] + np.array([cth * lip[0] - sth * lip[1], sth * lip[0] + cth * lip[1]])
            ys = np.linspace(wcfg.floor, pivot[1], max(2, int((pivot[1] - wcfg.floor) / 0.005)))
            drift = stream_speed * np.sqrt(2.0 * np.maximum(pivot[1] - ys, 0.0) / GRAVITY)
            fr = np.linspace(0.0, 1.0, max(2, int(drift.max() / 0.005) + 1))
            pts.append(np.stack([(pivot[0] - drift[:, None] * fr[None, :]).ravel(), np.repeat(ys, len(fr))], 1))
        pts = np.concatenate(pts)
        # only points within the plant's bounding box grown by CLEARANCE_CAP can be closer than that
        bb_lo, bb_hi = outline.min(0) - CLEARANCE_CAP, outline.max(0) + CLEARANCE_CAP
        pts = pts[((pts >= bb_lo) & (pts <= bb_hi)).all(1)]
        if len(pts) == 0:
            out[i] = CLEARANCE_CAP
            continue
        if _inside_plant(wcfg, jit, pts).any():
            out[i] = 0.0
            continue
        best = np.inf
        q2 = (outline**2).sum(1)[None, :]
        for k in range(0, len(pts), 2048):  # chunks keep the distance matrix small
            p = pts[k : k + 2048]
            best = min(best, float(((p**2).sum(1)[:, None] + q2 - 2.0 * p @ outline.T).min()))
        out[i] = min(CLEARANCE_CAP, math.sqrt(max(best, 0.0)))
    return out


def _inside_plant(wcfg: Any, jit: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Points inside a plant shape (sign of the colliders' SDF, which is exact at the surface)."""
    far = np.full(2, 1e6)
    plant = Obstacles([Body("plant", pose=wcfg.plant_pose(jit), shapes=wcfg.plant_shapes())], -far, far)
    d, _ = plant.sdf(pts)
    return d < 0
