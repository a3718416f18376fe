"""Train the dynamics model on source-world data, with a cache keyed by config hashes.

    python -m dynamics.train                                   # default config (48 batches of 32)
    python -m dynamics.train --config-name quick               # 4 batches: the main job's size
    python -m dynamics.train data.n_batches=4 train.max_epochs=50 cache_root=/tmp/dyn

Layout under ``cache_root`` (default ``.cache/dynamics``, relative to the working directory):
``data-<data_hash>/dataset.pt`` (+ ``config.yaml``; ``parts/`` holds finished batches while
generating, so an interrupted run resumes) and ``model-<model_hash>/model.pt`` (+ ``config.yaml``,
``metrics.json``). The data hash covers only data-generation fields and the world config's
content, the model hash the data hash plus model and training fields (see
:mod:`dynamics.config`), so changing e.g. ``train.lr`` retrains on the cached data. Concurrent
runs (Hydra multirun) wait on a file lock instead of generating the same data twice.

Shipped files: the default configuration's dataset and single models ship with the package under
``dynamics/shipped/`` (``source-<data_hash>.pt``, ``model-<model_hash>.pt``); the cache copies a shipped
file in instead of simulating or training when its hash is the one the requested configuration needs.
``python -m dynamics.shipped`` makes them (:mod:`dynamics.shipped`).
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import fcntl
import logging
import shutil
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import hydra
import numpy as np
import torch
import yaml
from tqdm.auto import tqdm

import configs
import safeio
from task import STATE_NAMES
from task.threads import torch_threads

from . import data as data_mod
from .config import (
    TRAIN_COMMAND,
    DataConfig,
    DynamicsConfig,
    DynamicsError,
    ModelConfig,
    TrainConfig,
    data_hash,
    model_hash,
    single_models,
    world_config,
)
from .data import MOVE, POUR, Transitions
from .ensemble import DynamicsEnsemble
from .model import SKILLS, LearnedDynamics

log = logging.getLogger(__name__)
CONFIG_DIR = configs.path("dynamics")
#: the shipped dataset and single models of the default configuration
SHIPPED_DIR = Path(__file__).resolve().parent / "shipped"

Generator = Callable[..., Transitions]


# ---------------------------------------------------------------------------------- training
def split_by_trajectory(traj: np.ndarray, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Train / validation row indices with whole trajectories on one side (no leakage between steps)."""
    ids = np.unique(traj)
    if len(ids) < 2:
        idx = np.arange(len(traj))
        return idx, idx[:0]
    perm = np.random.default_rng(seed).permutation(ids)
    n_val = min(len(ids) - 1, max(1, int(round(val_fraction * len(ids)))))
    val = np.isin(traj, perm[:n_val])
    return np.flatnonzero(~val), np.flatnonzero(val)


def fit(
    ds: Transitions,
    model_cfg: ModelConfig | None = None,
    train_cfg: TrainConfig | None = None,
    progress: bool = False,
    world_cfg: Any = None,
) -> LearnedDynamics:
    """Train a fresh :class:`LearnedDynamics` on ``ds``; seeded and bit-reproducible on CPU.

    ``world_cfg`` (``sim.world.WorldConfig`` or mapping; default: the default world) gives the
    controlled cup's geometry (pour inputs) and the distance weights. Loss: ``train_cfg.loss``
    (default: the state distance d with the world's weights, so training minimises the MDE's
    label); early stopping on the validation loss restores the best epoch.
    ``model.info["training"]`` gets the losses, epochs, wall time and validation errors.
    """
    wcfg = world_config(DataConfig(), world_cfg)
    cup = wcfg.controlled_cup
    w = {"pose": 1.0, "volume": 1.0, **dict(wcfg.distance_weights)}
    mc, tc = model_cfg or ModelConfig(), train_cfg or TrainConfig()
    ds.validate()
    if len(ds) < 2:
        raise DynamicsError(
            f"cannot train the dynamics model on {len(ds)} transition(s); generate more data "
            f"(data.n_batches) with `{TRAIN_COMMAND}`"
        )
    t0 = time.perf_counter()
    tr_idx, va_idx = split_by_trajectory(ds.traj, tc.val_fraction, tc.seed)
    skill = ds.skill()
    with torch_threads(tc.threads):
        torch.manual_seed(tc.seed)
        model = LearnedDynamics(mc)
        model.set_cup_geometry(cup.inner_width, cup.inner_height, cup.wall)
        missing = _set_statistics(model, ds, tr_idx, skill, mc)
        S, A, SN = (torch.from_numpy(np.ascontiguousarray(x)) for x in (ds.s, ds.a, ds.s_next))
        tr, va = torch.from_numpy(tr_idx), torch.from_numpy(va_idx)
        opt = torch.optim.Adam(model.parameters(), lr=tc.lr, weight_decay=tc.weight_decay)
        sched = (
            torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=tc.max_epochs) if tc.lr_schedule == "cosine" else None
        )
        gen = torch.Generator().manual_seed(tc.seed)

        def loss_of(idx: torch.Tensor) -> torch.Tensor:
            e = model(S[idx], A[idx]) - SN[idx]
            if tc.loss == "scaled_mse":
                return ((e / model.output_scale(A[idx])) ** 2).sum(1).mean()
            pose = torch.sqrt((e[:, :3] ** 2).sum(1) + 1e-10)  # eps: finite gradient at zero error
            return (w["pose"] * pose + w["volume"] * (e[:, 3].abs() + e[:, 4].abs())).mean()

        history, best, best_epoch = _train_epochs(model, loss_of, tr, va, opt, sched, gen, tc, progress)
    metrics = {
        "epochs_run": len(history),
        "best_epoch": best_epoch,
        "best_val_loss": best,
        "final_train_loss": history[-1][0],
        "final_lr": opt.param_groups[0]["lr"],
        "n_train": int(len(tr_idx)),
        "n_val": int(len(va_idx)),
        "untrained_skills": missing,
        "wall_seconds": time.perf_counter() - t0,
        "val_errors": error_table(model, ds.subset(va_idx), w) if len(va_idx) else {},
        "history": [[round(a, 6), round(b, 6)] for a, b in history],
    }
    model.info["training"] = metrics
    return model


def _set_statistics(model: LearnedDynamics, ds: Transitions, tr_idx: np.ndarray, skill: np.ndarray, mc: ModelConfig):
    """Each skill's network normalised on its training rows; returns the skills without any (left untrained)."""
    missing = []
    for k in (MOVE, POUR):
        rows = tr_idx[skill[tr_idx] == k]
        if len(rows) == 0:
            missing.append(SKILLS[k])
            continue
        model.nets[k].set_statistics(ds.s[rows], ds.a[rows], ds.s_next[rows], mc)
    if missing:
        log.warning("no training transitions of skill(s) %s: their network stays untrained", missing)
    return missing


def _train_epochs(model, loss_of, tr, va, opt, sched, gen, tc: TrainConfig, progress: bool):
    """Minibatch epochs in the generator's order until ``tc.patience`` epochs bring no better validation loss; the
    model is left at its best epoch, in eval mode. Returns (history of (train, val) losses, best val, best epoch)."""
    best, best_state, best_epoch, stale = float("inf"), copy.deepcopy(model.state_dict()), -1, 0
    history = []
    bar = tqdm(range(tc.max_epochs), desc="train dynamics", unit="epoch", disable=not progress)
    for epoch in bar:
        model.train()
        perm = tr[torch.randperm(len(tr), generator=gen)]
        total = 0.0
        for i in range(0, len(perm), tc.batch_size):
            idx = perm[i : i + tc.batch_size]
            loss = loss_of(idx)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(idx)
        if sched is not None:
            sched.step()
        model.eval()
        with torch.no_grad():
            val = float(loss_of(va)) if len(va) else total / len(tr)
        history.append((total / len(tr), val))
        if val < best:
            best, best_state, best_epoch, stale = val, copy.deepcopy(model.state_dict()), epoch, 0
        else:
            stale += 1
        bar.set_postfix(train=f"{total / len(tr):.4f}", val=f"{val:.4f}", best=best_epoch)
        if stale >= tc.patience:
            break
    bar.close()
    model.load_state_dict(best_state)
    model.eval()
    return history, best, best_epoch


def error_table(
    model: LearnedDynamics, ds: Transitions, distance_weights: Mapping[str, float] | None = None
) -> dict[str, Any]:
    """Mean absolute error per state component and mean state distance d(f_hat(s, a), s'), per skill."""
    if len(ds) == 0:
        return {"n": 0}
    pred = model.predict_np(ds.s, ds.a)
    return _errors(pred, ds.s_next.astype(float), ds.skill(), distance_weights)


def _errors(
    pred: np.ndarray, true: np.ndarray, skill: np.ndarray, distance_weights: Mapping[str, float] | None = None
) -> dict[str, Any]:
    w = {"pose": 1.0, "volume": 1.0, **(distance_weights or {})}
    err = np.abs(pred - true)
    d = w["pose"] * np.linalg.norm(pred[:, :3] - true[:, :3], axis=1) + w["volume"] * (err[:, 3] + err[:, 4])
    out: dict[str, Any] = {}
    for name, m in (("all", np.ones(len(err), bool)), ("move", skill == MOVE), ("pour", skill == POUR)):
        if m.any():
            out[name] = {
                "n": int(m.sum()),
                **{f"mae_{c}": float(err[m, j].mean()) for j, c in enumerate(STATE_NAMES)},
                "mean_d": float(d[m].mean()),
                "median_d": float(np.median(d[m])),
                "p90_d": float(np.quantile(d[m], 0.9)),
                "frac_d_gt_0.07": float((d[m] > 0.07).mean()),
            }
        else:
            out[name] = {"n": 0}
    return out


# ---------------------------------------------------------------------------------- cache
@contextlib.contextmanager
def _locked(folder: Path) -> Iterator[None]:
    """Exclusive lock on ``folder/.lock`` so that parallel runs do not generate the same thing twice."""
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / ".lock", "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _as_config(cfg: DynamicsConfig | Mapping[str, Any] | None) -> DynamicsConfig:
    return cfg if isinstance(cfg, DynamicsConfig) else DynamicsConfig.from_dict(cfg)


def cache_paths(
    cfg: DynamicsConfig | Mapping[str, Any] | None = None, cache_root: str | Path | None = None, world_cfg: Any = None
) -> dict[str, Any]:
    """Where the dataset and the checkpoint for ``cfg`` live (whether or not they exist yet)."""
    c = _as_config(cfg)
    root = Path(cache_root if cache_root is not None else c.cache_root)
    dh = data_hash(c, world_cfg)
    mh = model_hash(c, dh)
    return {
        "root": root,
        "data_hash": dh,
        "model_hash": mh,
        "dataset": root / f"data-{dh}" / "dataset.pt",
        "checkpoint": root / f"model-{mh}" / "model.pt",
    }


def load_or_generate_dataset(
    cfg: DynamicsConfig | Mapping[str, Any] | None = None,
    cache_root: str | Path | None = None,
    generator: Generator | None = None,
    progress: bool | None = None,
    world_cfg: Any = None,
    use_shipped: bool = True,
) -> Transitions:
    """The source-world training data for ``cfg``: loaded from the cache, generated only when missing.

    ``generator(cfg, shard_dir=..., progress=..., world_cfg=...) -> Transitions`` defaults to
    :func:`dynamics.data.generate_source_dataset` (the simulator). With the default generator and
    ``use_shipped``, a dataset shipped with the package for the same data hash
    (:mod:`dynamics.shipped`) is copied into the cache instead of simulating it.
    """
    c = _as_config(cfg)
    p = cache_paths(c, cache_root, world_cfg)
    path, dh = p["dataset"], p["data_hash"]
    folder, shard_dir = path.parent, path.parent / "parts"
    if not path.is_file() or _unfinished_data(path):
        with _locked(folder):
            _remove_orphans(folder, shard_dir)
            if not path.is_file() and generator is None and use_shipped:
                install_shipped(path, dh)
            if not path.is_file():
                show = c.progress if progress is None else progress
                if generator is None and c.data.pour_batches:  # the random data's own dataset + focused pours
                    base = load_or_generate_dataset(
                        c.replace(data=dataclasses.replace(c.data, pour_batches=0)),
                        cache_root,
                        None,
                        progress,
                        world_cfg,
                        use_shipped,
                    )
                    pours = data_mod.generate_transitions(
                        c.data, "source", shard_dir=shard_dir, progress=show, world_cfg=world_cfg, pours=True
                    )
                    ds = Transitions.concat([base, pours], meta={**base.meta, "pours": pours.meta})
                else:
                    gen = generator or data_mod.generate_source_dataset
                    ds = gen(c, shard_dir=shard_dir, progress=show, world_cfg=world_cfg)
                if len(ds) == 0:
                    raise DynamicsError(
                        "the data generator returned no transitions (all environments unstable?); "
                        "check the world config or change data.seed"
                    )
                ds.meta = {**ds.meta, "data_hash": dh, "config": c.to_dict()}
                ds.save(path)
                log.info("wrote %s (%d transitions)", path, len(ds))
            _finish_data(path, c, dh)
    ds = Transitions.load(path, expected_hash=dh)
    if ds.meta.get("world", "source") != "source":
        raise DynamicsError(
            f"{path} holds {ds.meta.get('world')}-world data; the dynamics model is trained on the "
            f"source world only. Delete it and regenerate with `{TRAIN_COMMAND}`"
        )
    return ds


def _unfinished_data(path: Path) -> bool:
    """The dataset's folder lacks its config.yaml or still has parts/ (a writer killed right after saving)."""
    return not (path.parent / "config.yaml").is_file() or (path.parent / "parts").exists()


def _finish_data(path: Path, c: DynamicsConfig, dh: str) -> None:
    """Write the dataset folder's config.yaml and drop its shards (call with the folder's lock held)."""
    if not (path.parent / "config.yaml").is_file():
        safeio.write_text(path.parent / "config.yaml", yaml.safe_dump({"data": c.to_dict()["data"], "data_hash": dh}))
    shutil.rmtree(path.parent / "parts", ignore_errors=True)


def load_or_train(
    cfg: DynamicsConfig | Mapping[str, Any] | None = None,
    cache_root: str | Path | None = None,
    *,
    world_cfg: Any = None,
    generator: Generator | None = None,
    progress: bool | None = None,
    use_shipped: bool = True,
) -> LearnedDynamics | DynamicsEnsemble:
    """The trained model for ``cfg`` (a DynamicsConfig or a plain / OmegaConf mapping of its fields).

    Loads the cached checkpoint if its config hash matches; otherwise trains (and, if needed,
    generates the dataset first). ``cache_root`` overrides ``cfg.cache_root``; ``world_cfg`` (the
    experiment's world config: WorldConfig or mapping) overrides the ``data.world`` file and is
    part of both hashes. ``model.ensemble`` > 1: a :class:`~dynamics.ensemble.DynamicsEnsemble` whose
    members are cached as single models (:func:`dynamics.config.ensemble_member`). With the default
    generator and ``use_shipped``, a checkpoint shipped with the package for the same model hash
    (:mod:`dynamics.shipped`) is copied into the cache instead of training.
    """
    c = _as_config(cfg)
    p = cache_paths(c, cache_root, world_cfg)
    if c.model.ensemble > 1:
        return _load_or_train_ensemble(
            c, p, world_cfg=world_cfg, generator=generator, progress=progress, use_shipped=use_shipped
        )
    ckpt, mh = p["checkpoint"], p["model_hash"]
    folder = ckpt.parent
    if p["dataset"].is_file() and _unfinished_data(p["dataset"]):  # finish it even when the model is cached
        with _locked(p["dataset"].parent):
            _remove_orphans(p["dataset"].parent, p["dataset"].parent / "parts")
            _finish_data(p["dataset"], c, p["data_hash"])
    if not ckpt.is_file() or not (folder / "metrics.json").is_file():
        with _locked(folder):
            _remove_orphans(folder)
            if not ckpt.is_file() and generator is None and use_shipped:
                install_shipped_model(ckpt, mh)
            if not ckpt.is_file():
                ds = load_or_generate_dataset(c, p["root"], generator, progress, world_cfg)
                model = fit(
                    ds,
                    c.model,
                    c.train,
                    progress=c.progress if progress is None else progress,
                    world_cfg=world_config(c.data, world_cfg),
                )
                model.info.update(
                    {
                        "model_hash": mh,
                        "data_hash": p["data_hash"],
                        "config": c.to_dict(),
                        "dataset": {
                            "path": str(p["dataset"]),
                            **ds.summary(),
                            "generation_wall_seconds": ds.meta.get("wall_seconds"),
                        },
                    }
                )
                model.save(ckpt)
                log.info("wrote %s", ckpt)
            # also finishes a directory whose writer was killed after saving the checkpoint
            if not (folder / "config.yaml").is_file() or not (folder / "metrics.json").is_file():
                info = LearnedDynamics.load(ckpt, expected_hash=mh).info
                safeio.write_text(
                    folder / "config.yaml",
                    yaml.safe_dump({**c.to_dict(), "model_hash": mh, "data_hash": p["data_hash"]}),
                )
                metrics = {k: v for k, v in info["training"].items() if k != "history"}
                safeio.write_json(folder / "metrics.json", metrics, indent=1)
    return LearnedDynamics.load(ckpt, expected_hash=mh)


def is_cached(
    cfg: DynamicsConfig | Mapping[str, Any] | None = None, cache_root: str | Path | None = None, world_cfg: Any = None
) -> bool:
    """Whether :func:`load_or_train` finds everything for ``cfg`` in the cache and writes nothing there: every
    single model's checkpoint and metrics (an ensemble caches its members, never itself), and no unfinished
    dataset. A run may then use a read-only cache."""
    c = _as_config(cfg)
    for m in single_models(c):
        p = cache_paths(m, cache_root, world_cfg)
        if not (p["checkpoint"].is_file() and (p["checkpoint"].parent / "metrics.json").is_file()):
            return False
        if p["dataset"].is_file() and _unfinished_data(p["dataset"]):
            return False
    return True


def _load_or_train_ensemble(c: DynamicsConfig, p: dict[str, Any], **kwargs: Any) -> DynamicsEnsemble:
    """The ensemble of ``c``: each member loaded (or trained) and cached as a single model of its own."""
    members = [load_or_train(m, p["root"], **kwargs) for m in single_models(c)]
    return DynamicsEnsemble(
        members,
        info={
            "model_hash": p["model_hash"],
            "data_hash": p["data_hash"],
            "config": c.to_dict(),
            "members": [m.info["model_hash"] for m in members],
            "dataset": members[0].info.get("dataset"),
            "training": {"members": [{k: v for k, v in m.info["training"].items() if k != "history"} for m in members]},
        },
    )


def _remove_orphans(*folders: Path) -> None:
    """Temporary files a killed writer left (call with the folder's lock held)."""
    for f in folders:
        for tmp in safeio.remove_orphans(f):
            log.info("removed %s, left by a killed writer", tmp)


# ---------------------------------------------------------------------------------- shipped files
def shipped_path(data_hash: str) -> Path:
    """Where the shipped dataset of a data hash lives (whether or not it exists)."""
    return SHIPPED_DIR / f"source-{data_hash}.pt"


def find_shipped(data_hash: str) -> Path | None:
    """The shipped dataset for ``data_hash``, or None (the shipped files of other hashes are named in the log;
    ``tests/test_dynamics_shipped.py`` fails when the default config's file is missing or stale)."""
    path = shipped_path(data_hash)
    if path.is_file():
        return path
    others = sorted(p.name for p in SHIPPED_DIR.glob("source-*.pt")) if SHIPPED_DIR.is_dir() else []
    if others:
        log.info(
            "the shipped source-world dataset(s) %s were made by another configuration (this one needs "
            "data hash %s): generating the data instead (run `python -m dynamics.shipped` to refresh "
            "the shipped file)",
            others,
            data_hash,
        )
    return None


def shipped_model_path(model_hash: str) -> Path:
    """Where the shipped checkpoint of a (single-model) model hash lives (whether or not it exists)."""
    return SHIPPED_DIR / f"model-{model_hash}.pt"


def install_shipped_model(checkpoint: Path, model_hash: str) -> bool:
    """Copy the shipped checkpoint for ``model_hash`` to ``checkpoint`` (atomically); False if there is none."""
    src = shipped_model_path(model_hash)
    if not src.is_file():
        if SHIPPED_DIR.is_dir() and any(SHIPPED_DIR.glob("model-*.pt")):
            log.info(
                "no shipped dynamics model for model hash %s (the shipped ones were trained with another "
                "configuration): training it",
                model_hash,
            )
        return False
    try:  # a damaged or mislabelled file is never copied into the cache
        LearnedDynamics.load(src, expected_hash=model_hash)
    except DynamicsError as e:
        log.warning("the shipped dynamics model %s cannot be used (%s): training it instead", src.name, e)
        return False
    safeio.atomic_write(checkpoint, src.read_bytes())
    log.info("using the shipped dynamics model %s", src.name)
    return True


def install_shipped(dataset: Path, data_hash: str) -> bool:
    """Copy the shipped dataset for ``data_hash`` to ``dataset`` (atomically); False if there is none."""
    src = find_shipped(data_hash)
    if src is None:
        return False
    safeio.atomic_write(dataset, src.read_bytes())
    log.info("using the shipped source-world dataset %s (data hash %s)", src.name, data_hash)
    return True


# ---------------------------------------------------------------------------------- CLI
def format_errors(table: Mapping[str, Any], title: str = "") -> str:
    cols = ["n", *[f"mae_{c}" for c in STATE_NAMES], "mean_d", "p90_d", "frac_d_gt_0.07"]
    lines = [title] if title else []
    lines.append(f"{'':6s}" + "".join(f"{c:>15s}" for c in cols))
    for name, row in table.items():
        if not isinstance(row, Mapping) or not row.get("n"):
            continue
        lines.append(f"{name:6s}" + "".join(f"{row[c]:>15d}" if c == "n" else f"{row[c]:>15.4g}" for c in cols))
    return "\n".join(lines)


def _run(cfg: Any) -> LearnedDynamics | DynamicsEnsemble:
    logging.basicConfig(level=logging.INFO)
    c = DynamicsConfig.from_dict(cfg)
    p = cache_paths(c)
    t0 = time.perf_counter()
    singles = single_models(c)
    had_data = p["dataset"].is_file()
    had_model = [
        "cached"
        if cache_paths(m)["checkpoint"].is_file()
        else "shipped"
        if shipped_model_path(cache_paths(m)["model_hash"]).is_file()
        else "trained"
        for m in singles
    ]
    model = load_or_train(c)
    info = model.info
    print(f"dataset    {p['dataset']} ({'cached' if had_data else 'generated'}): {info['dataset']}")
    if info["dataset"].get("generation_wall_seconds") is not None:
        print(f"           generation wall time {info['dataset']['generation_wall_seconds']:.1f} s")
    for m, had in zip(getattr(model, "members", [model]), had_model):
        tr = m.info["training"]
        print(
            f"checkpoint {cache_paths(m.info['config'])['checkpoint']} ({had}): "
            f"best epoch {tr['best_epoch']} of {tr['epochs_run']}, val loss {tr['best_val_loss']:.4f}, "
            f"training wall time {tr['wall_seconds']:.1f} s"
        )
        print(format_errors(tr["val_errors"], "validation split (source world), mean absolute errors:"))
    print(f"total wall time of this command {time.perf_counter() - t0:.1f} s")
    return model


def main(argv: list[str] | None = None) -> None:
    """Hydra entry point (``configs/dynamics``); any field can be overridden as ``key=value``."""
    if argv is not None:
        sys.argv = [sys.argv[0], *argv]
    hydra.main(config_path=str(CONFIG_DIR), config_name="default", version_base=None)(_run)()


if __name__ == "__main__":
    main()
