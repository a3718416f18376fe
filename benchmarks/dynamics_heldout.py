"""Training variants of the dynamics model compared on source-world data none of them saw:
``python -m benchmarks.dynamics_heldout --out FILE [--heldout-batches 96] [--seeds 0 1 2]
[--variant NAME=key=value,key=value ...]``.

Why: a model's own validation split is a few hundred transitions and differs between training
seeds, so it cannot rank variants. Batch b of the source-world data depends only on (data seed, b,
world) (:func:`dynamics.data.generate_transitions`), so the batches past the configured
``data.n_batches`` of a larger set (``--heldout-batches``, cached like any dataset; generated if
missing) are fresh trajectories from the same distribution. Every variant is trained (or loaded
from the cache) with each seed and scored there: the state distance d and the error of v_tgt on
all pours, and the error and bias of v_tgt on the pours that moved water (|dv_tgt| > 0.02), which
are the pours a plan needs; then the same for the mean of the seeds' models.

Variants are overrides of ``configs/dynamics`` (default: the default config as it is), e.g.
``--variant constant=train.lr_schedule=constant,train.max_epochs=1000,train.batch_size=128,train.lr=0.002``.
Each model is a single one (``model.ensemble=1``): the "mean of seeds" row is the ensemble.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from benchmarks._cli import report
from task import state_distance


def scores(pred: np.ndarray, ds: Any) -> dict[str, float]:
    """Errors of predictions ``pred`` [n, 5] on transitions ``ds``: pours, and pours that moved water."""
    true = ds.s_next.astype(float)
    pour = ds.skill() == 1
    moved = pour & (np.abs(ds.s_next[:, 4] - ds.s[:, 4]) > 0.02)
    d = state_distance(pred, true)
    e = pred[:, 4] - true[:, 4]
    return {"pour_mean_d": float(d[pour].mean()), "pour_mae_v_tgt": float(np.abs(e[pour]).mean()),
            "moved_mae_v_tgt": float(np.abs(e[moved]).mean()), "moved_bias_v_tgt": float(e[moved].mean()),
            "move_mean_d": float(d[~pour].mean()), "n_pour": int(pour.sum()), "n_moved": int(moved.sum())}


def run(variants: dict[str, list[str]], seeds: Sequence[int], heldout_batches: int) -> dict[str, Any]:
    from dynamics import load_or_generate_dataset, load_or_train
    from dynamics.evaluate import compose_config

    out: dict[str, Any] = {"heldout_batches": heldout_batches, "seeds": list(seeds), "variants": {}}
    held = None
    for name, overrides in variants.items():
        cfg = compose_config("default", ["model.ensemble=1", *overrides])
        if held is None:
            data, n_train = cfg.data, cfg.data.n_batches
            if heldout_batches <= n_train:
                raise ValueError(f"--heldout-batches {heldout_batches}: allowed > data.n_batches = {n_train}")
            big = load_or_generate_dataset(dataclasses.replace(cfg, data=dataclasses.replace(
                cfg.data, n_batches=heldout_batches)))
            held = big.subset(np.flatnonzero(big.traj >= n_train * cfg.data.batch_size))
            out["heldout"] = {"batches": [n_train, heldout_batches], "transitions": len(held)}
        elif cfg.data != data:
            raise ValueError(f"variant {name}: its data.* differ from the first variant's; all variants must share "
                             "the training data to be scored on the same held-out batches")
        rows, preds = [], []
        for s in seeds:
            model = load_or_train(dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, seed=int(s))),
                                  progress=False)
            pred = model.predict_np(held.s, held.a)
            preds.append(pred)
            tr = model.info["training"]
            rows.append({"seed": int(s), **scores(pred, held), "epochs_run": tr["epochs_run"],
                         "best_epoch": tr["best_epoch"], "training_seconds": tr["wall_seconds"]})
        out["variants"][name] = {"overrides": overrides, "per_seed": rows,
                                 "mean_of_seeds": scores(np.mean(preds, axis=0), held)}
    return out


def format_table(r: dict[str, Any]) -> str:
    cols = ("pour_mean_d", "pour_mae_v_tgt", "moved_mae_v_tgt", "moved_bias_v_tgt")
    h = r["heldout"]
    lines = [f"held-out source batches {h['batches'][0]}-{h['batches'][1] - 1} ({h['transitions']} transitions)",
             f"{'variant':<14}{'model':<14}" + "".join(f"{c:>18}" for c in cols) + f"{'epochs':>8}{'train s':>9}"]
    for name, v in r["variants"].items():
        for row in v["per_seed"]:
            lines.append(f"{name:<14}{'seed ' + str(row['seed']):<14}" + "".join(f"{row[c]:>18.4f}" for c in cols)
                         + f"{row['epochs_run']:>8d}{row['training_seconds']:>9.0f}")
        m = v["mean_of_seeds"]
        lines.append(f"{name:<14}{'mean of seeds':<14}" + "".join(f"{m[c]:>18.4f}" for c in cols))
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.dynamics_heldout", description=__doc__.split("\n\n")[0])
    ap.add_argument("--heldout-batches", type=int, default=96,
                    help="size of the larger dataset whose batches past data.n_batches are the held-out set")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="training seeds per variant")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME=OVERRIDES",
                    help="a named variant: comma-separated overrides of configs/dynamics (repeatable)")
    ap.add_argument("--out", type=Path, default=None, help="write the result as JSON here")
    args = ap.parse_args(argv)
    variants: dict[str, list[str]] = {}
    for v in args.variant or ["default="]:
        name, sep, over = v.partition("=")
        if not sep or not name:
            ap.error(f"--variant {v!r}: allowed NAME=key=value,key=value (or NAME= for the default config)")
        variants[name] = [o for o in over.split(",") if o]
    r = run(variants, args.seeds, args.heldout_batches)
    report(format_table(r), r, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
