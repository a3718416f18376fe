"""Where is the source-trained model wrong? Errors on held-out source data and on the target world.

    python -m dynamics.evaluate --out DIR [--config-name quick] [key=value ...]

Trains (or loads from the cache) the model of the given config, generates (or loads from the
cache) a fresh source-world test set and a small target-world set (plant present, its pose
jittered per trajectory like a planning problem's), and reports for each group the mean absolute
error per state component and the state distance d(f_hat(s, a), s') (``sim.world`` weights):

* ``source_val``: the training run's validation split (held-out source trajectories; for an
  ensemble, the trajectories held out by every member);
* ``source_test``: fresh source-world trajectories (``eval.seed``);
* ``target_far`` / ``target_near``: target-world transitions whose cup path and (for a pour) the
  water's fall region stay farther than / come within ``eval.near_radius`` of the plant (see
  :func:`dynamics.data.plant_clearance` and :class:`dynamics.config.EvalConfig`).

Writes ``DIR/dynamics_eval.json`` (all numbers, definitions, config), ``DIR/dynamics_eval.png``
(bar plots + d versus plant clearance) and prints the table.
"""

from __future__ import annotations

import argparse
import logging
import shutil
from pathlib import Path
from typing import Any

import numpy as np
from hydra import compose, initialize_config_dir

import safeio
from task import STATE_NAMES

from .config import DynamicsConfig, _digest, _plain, data_hash, ensemble_member, plant_dict, world_config
from .data import CLEARANCE_CAP, Transitions, generate_transitions, plant_clearance
from .train import (
    CONFIG_DIR,
    _errors,
    _locked,
    cache_paths,
    format_errors,
    load_or_generate_dataset,
    load_or_train,
    split_by_trajectory,
)

log = logging.getLogger(__name__)
GROUPS = ("source_val", "source_test", "target_far", "target_near")


def compose_config(config_name: str = "default", overrides: list[str] | None = None) -> DynamicsConfig:
    """The same config ``python -m dynamics.train --config-name NAME OVERRIDES`` would use."""
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base=None):
        return DynamicsConfig.from_dict(compose(config_name=config_name, overrides=list(overrides or [])))


def eval_sets(
    cfg: DynamicsConfig, cache_root: str | Path | None = None, world_cfg: Any = None
) -> dict[str, Transitions]:
    """Fresh source- and target-world transition sets (cached by data hash + eval seed and sizes)."""
    root = cache_paths(cfg, cache_root, world_cfg)["root"]
    key = _digest(
        {
            "data": data_hash(cfg, world_cfg),
            "plant": plant_dict(cfg.data, world_cfg),
            "seed": cfg.eval.seed,
            "source": cfg.eval.source_batches,
            "target": cfg.eval.target_batches,
        }
    )
    folder = root / f"eval-{key}"
    out = {}
    for world, n in (("source", cfg.eval.source_batches), ("target", cfg.eval.target_batches)):
        if n == 0:
            continue
        path = folder / f"{world}.pt"
        with _locked(folder):
            safeio.remove_orphans(folder)  # left by a writer killed mid-write
            if not path.is_file():
                # natural distribution in evaluation: keep every stuck sequence
                ds = generate_transitions(
                    cfg.data,
                    world,
                    n_batches=n,
                    seed=cfg.eval.seed,
                    keep_all_stuck=True,
                    progress=cfg.progress,
                    shard_dir=folder / f"parts-{world}",
                    meta={"eval_key": key},
                    world_cfg=world_cfg,
                )
                ds.save(path)
            shutil.rmtree(folder / f"parts-{world}", ignore_errors=True)  # also after a kill right after saving
        out[world] = Transitions.load(path)
    return out


def evaluate(cfg: DynamicsConfig, cache_root: str | Path | None = None, world_cfg: Any = None) -> dict[str, Any]:
    """All groups' error tables plus per-transition (clearance, d) pairs of the target set."""
    model = load_or_train(cfg, cache_root, world_cfg=world_cfg)
    train_ds = load_or_generate_dataset(cfg, cache_root, world_cfg=world_cfg)
    members = [ensemble_member(cfg, k) for k in range(cfg.model.ensemble)] if cfg.model.ensemble > 1 else [cfg]
    va = np.arange(len(train_ds))  # held out: in the validation split of every member (few rows for an ensemble)
    for m in members:
        va = np.intersect1d(va, split_by_trajectory(train_ds.traj, m.train.val_fraction, m.train.seed)[1])
    sets = eval_sets(cfg, cache_root, world_cfg)
    wcfg = world_config(cfg.data, world_cfg)
    w = wcfg.distance_weights
    groups: dict[str, Transitions] = {"source_val": train_ds.subset(va)}
    if "source" in sets:
        groups["source_test"] = sets["source"]
    scatter: dict[str, list] = {}
    if "target" in sets:
        tgt = sets["target"]
        clearance = plant_clearance(wcfg, tgt, "target", cfg.eval.stream_speed)
        near = clearance < cfg.eval.near_radius
        groups["target_far"] = tgt.subset(np.flatnonzero(~near))
        groups["target_near"] = tgt.subset(np.flatnonzero(near))
        pred = model.predict_np(tgt.s, tgt.a)
        err = np.abs(pred - tgt.s_next)
        d = w["pose"] * np.linalg.norm(pred[:, :3] - tgt.s_next[:, :3], axis=1) + w["volume"] * (err[:, 3] + err[:, 4])
        scatter = {
            "clearance": clearance.tolist(),
            "d": d.tolist(),
            "skill": tgt.skill().tolist(),
            "stuck": tgt.stuck.astype(bool).tolist(),
        }
    tables = {}
    for name, ds in groups.items():
        if len(ds) == 0:
            tables[name] = {"all": {"n": 0}}
            continue
        pred = model.predict_np(ds.s, ds.a)
        tables[name] = _errors(pred, ds.s_next.astype(float), ds.skill(), w)
        tables[name]["all"]["stuck"] = int(ds.stuck.sum())
    return {
        "model_hash": model.info.get("model_hash"),
        "data_hash": model.info.get("data_hash"),
        "training": {k: v for k, v in model.info.get("training", {}).items() if k not in ("history", "val_errors")},
        "dataset": model.info.get("dataset"),
        "eval_sets": {
            k: {
                **v.summary(),
                "wall_seconds": v.meta.get("wall_seconds"),
                "categories": v.meta.get("counts", {}).get("categories"),
            }
            for k, v in sets.items()
        },
        "groups": tables,
        "target_scatter": scatter,
        "config": cfg.to_dict(),
        "definitions": {
            "mae_*": "mean |f_hat(s,a) - s'| per state component (m, m, rad, fraction, fraction)",
            "d": "task.state_distance(f_hat(s,a), s') with the world's distance weights",
            "frac_d_gt_0.07": "share of transitions with d > 0.07 (the paper's d_max)",
            "near": f"plant within {cfg.eval.near_radius} m of the cup outline along the action's executed "
            "path or, for a pour, of the water's fall region (between the vertical below the pouring "
            f"lip and the ballistic path of water leaving it at {cfg.eval.stream_speed} m/s towards -x)",
            "source_val": "validation split (whole held-out trajectories) of the training data; "
            "for an ensemble, the trajectories every member held out",
            "source_test": f"fresh source-world trajectories, seed {cfg.eval.seed}",
        },
    }


def plot(result: dict[str, Any], path: Path) -> None:
    import matplotlib  # only to plot: matplotlib takes about half a second to import

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = [g for g in GROUPS if result["groups"].get(g, {}).get("all", {}).get("n")]
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.5))
    ax = axes[0]
    width = 0.8 / max(1, len(groups))
    for i, g in enumerate(groups):
        row = result["groups"][g]["all"]
        vals = [row[f"mae_{c}"] for c in STATE_NAMES] + [row["mean_d"]]
        ax.bar(np.arange(6) + i * width, vals, width, label=f"{g} (n={row['n']})")
    ax.set_xticks(np.arange(6) + width * (len(groups) - 1) / 2, [*STATE_NAMES, "mean d"])
    ax.set_ylabel("mean absolute error (m, rad, fraction)")
    ax.set_title("error per state component")
    ax.legend(fontsize=8)
    ax = axes[1]
    for j, skill in enumerate(("move", "pour")):
        vals = [result["groups"][g].get(skill, {}).get("frac_d_gt_0.07", 0.0) for g in groups]
        ax.bar(np.arange(len(groups)) + j * 0.4, vals, 0.4, label=skill)
    ax.set_xticks(np.arange(len(groups)) + 0.2, groups, fontsize=8)
    ax.set_ylabel("share of transitions with d > 0.07")
    ax.set_title("large deviations by skill")
    ax.legend()
    ax = axes[2]
    sc = result.get("target_scatter") or {}
    if sc:
        c = np.asarray(sc["clearance"])
        d = np.asarray(sc["d"])
        sk = np.asarray(sc["skill"])
        for k, (name, mk) in enumerate((("move", "o"), ("pour", "^"))):
            m = sk == k
            ax.scatter(c[m], d[m], s=12, marker=mk, alpha=0.6, label=name)
        r = result["config"]["eval"]["near_radius"]
        ax.axvline(r, color="k", ls="--", lw=1, label=f"near radius {r} m")
        ax.axhline(0.07, color="r", ls=":", lw=1, label="d_max 0.07")
        ax.set_xlabel(f"plant clearance (m, capped at {CLEARANCE_CAP})")
        ax.set_ylabel("d(f_hat(s,a), s')")
        ax.set_title("target world: deviation vs distance to the plant")
        ax.legend(fontsize=8)
    fig.tight_layout()
    safeio.save_figure(fig, path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(
        prog="python -m dynamics.evaluate", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--out", required=True, help="output folder for dynamics_eval.json / .png")
    ap.add_argument("--config-name", default="default", help="config in configs/dynamics (default: default)")
    ap.add_argument("overrides", nargs="*", help="Hydra-style overrides, e.g. data.n_batches=4 eval.target_batches=2")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    cfg = compose_config(args.config_name, args.overrides)
    result = evaluate(cfg)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    safeio.write_json(out / "dynamics_eval.json", result, indent=1, default=_plain)
    plot(result, out / "dynamics_eval.png")
    print(f"model {result['model_hash']} (data {result['data_hash']}); eval sets: {result['eval_sets']}")
    for g in GROUPS:
        if g in result["groups"]:
            print(format_errors(result["groups"][g], f"\n[{g}]"))
    print(f"\nwrote {out / 'dynamics_eval.json'} and {out / 'dynamics_eval.png'}")
    return result


if __name__ == "__main__":
    main()
