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

``--heldout-data FILE`` scores on a cached dataset of another data config instead (for variants
whose training data differ, e.g. a data-coverage change); its transitions that also occur in a
variant's training data are dropped (datasets of one seed share their first trajectories).
The "clean" columns are the pours that moved water and spilled under the problems' 2 % limit: the
only pours a successful plan can use, a minority of the data (BENCHMARKS.md, "Dynamics model accuracy").

Variants are overrides of ``configs/dynamics`` (default: the default config as it is), e.g.
``--variant constant=train.lr_schedule=constant,train.max_epochs=1000,train.batch_size=128,train.lr=0.002``.
Each model is a single one (``model.ensemble=1``): the "mean of seeds" row is the ensemble.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from benchmarks._cli import report
from task import state_distance

#: spill (fraction of all water) under which a pour counts as "clean": the problems' max_spill
CLEAN_SPILL = 0.02


def scores(pred: np.ndarray, ds: Any) -> dict[str, float]:
    """Errors of predictions ``pred`` [n, 5] on transitions ``ds``: pours, and pours that moved water."""
    true = ds.s_next.astype(float)
    pour = ds.skill() == 1
    moved = pour & (np.abs(ds.s_next[:, 4] - ds.s[:, 4]) > 0.02)
    spilled = (ds.s[:, 3] + ds.s[:, 4]) - (ds.s_next[:, 3] + ds.s_next[:, 4])  # water this pour spilled
    clean = moved & (spilled < CLEAN_SPILL)
    d = state_distance(pred, true)
    e = pred[:, 4] - true[:, 4]
    mean = lambda v, m: float(v[m].mean()) if m.any() else float("nan")  # noqa: E731
    return {
        "pour_mean_d": mean(d, pour),
        "pour_mae_v_tgt": mean(np.abs(e), pour),
        "moved_mae_v_tgt": mean(np.abs(e), moved),
        "moved_bias_v_tgt": mean(e, moved),
        "clean_mae_v_tgt": mean(np.abs(e), clean),
        "clean_bias_v_tgt": mean(e, clean),
        "move_mean_d": mean(d, ~pour),
        "n_pour": int(pour.sum()),
        "n_moved": int(moved.sum()),
        "n_clean": int(clean.sum()),
    }


def _unseen(held: Any, train: Any) -> np.ndarray:
    """Rows of ``held`` whose (s, a) is not a row of ``train``."""
    key = lambda t: {r.tobytes() for r in np.c_[t.s, t.a].astype(np.float32)}  # noqa: E731
    seen = key(train)
    return np.array([r.tobytes() not in seen for r in np.c_[held.s, held.a].astype(np.float32)], dtype=bool)


def run(
    variants: dict[str, list[str]], seeds: Sequence[int], heldout_batches: int, heldout_data: Path | None = None
) -> dict[str, Any]:
    from dynamics import load_or_generate_dataset, load_or_train
    from dynamics.data import Transitions
    from dynamics.evaluate import compose_config

    out: dict[str, Any] = {"heldout_batches": heldout_batches, "seeds": list(seeds), "variants": {}}
    held = None
    configs = {name: compose_config("default", ["model.ensemble=1", *o]) for name, o in variants.items()}
    if heldout_data is not None:  # every variant is scored on the rows none of them trained on
        held = Transitions.load(heldout_data)
        out["heldout"] = {"file": str(heldout_data), "transitions": len(held)}
        for cfg in configs.values():
            held = held.subset(np.flatnonzero(_unseen(held, load_or_generate_dataset(cfg))))
        out["heldout"]["unseen_transitions"] = len(held)
    for name, overrides in variants.items():
        cfg = configs[name]
        if held is None:  # the batches past the training data (the same for every variant)
            data, n_train = cfg.data, cfg.data.n_batches
            if heldout_batches <= n_train:
                raise ValueError(f"--heldout-batches {heldout_batches}: allowed > data.n_batches = {n_train}")
            big = load_or_generate_dataset(
                dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, n_batches=heldout_batches))
            )
            held = big.subset(np.flatnonzero(big.traj >= n_train * cfg.data.batch_size))
            out["heldout"] = {"batches": [n_train, heldout_batches], "transitions": len(held)}
        elif heldout_data is None and cfg.data != data:
            raise ValueError(
                f"variant {name}: its data.* differ from the first variant's; all variants must share "
                "the training data to be scored on the same held-out batches"
            )
        rows, preds = [], []
        for s in seeds:
            model = load_or_train(
                dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, seed=int(s))), progress=False
            )
            pred = model.predict_np(held.s, held.a)
            preds.append(pred)
            tr = model.info["training"]
            rows.append(
                {
                    "seed": int(s),
                    **scores(pred, held),
                    "epochs_run": tr["epochs_run"],
                    "best_epoch": tr["best_epoch"],
                    "training_seconds": tr["wall_seconds"],
                }
            )
        out["variants"][name] = {
            "overrides": overrides,
            "per_seed": rows,
            "mean_of_seeds": scores(np.mean(preds, axis=0), held),
        }
    return out


def format_table(r: dict[str, Any]) -> str:
    cols = ("pour_mean_d", "moved_mae_v_tgt", "moved_bias_v_tgt", "clean_mae_v_tgt", "clean_bias_v_tgt")
    h = r["heldout"]
    what = (
        f"{h['file']} ({h['unseen_transitions']} transitions no variant trained on)"
        if "file" in h
        else f"source batches {h['batches'][0]}-{h['batches'][1] - 1} ({h['transitions']} transitions)"
    )
    lines = [
        f"held out: {what}",
        f"{'variant':<14}{'model':<14}" + "".join(f"{c:>18}" for c in cols) + f"{'epochs':>8}{'train s':>9}",
    ]
    for name, v in r["variants"].items():
        for row in v["per_seed"]:
            lines.append(
                f"{name:<14}{'seed ' + str(row['seed']):<14}"
                + "".join(f"{row[c]:>18.4f}" for c in cols)
                + f"{row['epochs_run']:>8d}{row['training_seconds']:>9.0f}"
            )
        m = v["mean_of_seeds"]
        lines.append(f"{name:<14}{'mean of seeds':<14}" + "".join(f"{m[c]:>18.4f}" for c in cols))
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.dynamics_heldout", description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--heldout-batches",
        type=int,
        default=96,
        help="size of the larger dataset whose batches past data.n_batches are the held-out set",
    )
    ap.add_argument(
        "--heldout-data",
        type=Path,
        default=None,
        metavar="FILE",
        help="score on this cached dataset (dataset.pt of another data config) instead",
    )
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="training seeds per variant")
    ap.add_argument(
        "--variant",
        action="append",
        default=[],
        metavar="NAME=OVERRIDES",
        help="a named variant: comma-separated overrides of configs/dynamics (repeatable)",
    )
    ap.add_argument("--out", type=Path, default=None, help="write the result as JSON here")
    args = ap.parse_args(argv)
    variants: dict[str, list[str]] = {}
    for v in args.variant or ["default="]:
        name, sep, over = v.partition("=")
        if not sep or not name:
            ap.error(f"--variant {v!r}: allowed NAME=key=value,key=value (or NAME= for the default config)")
        variants[name] = [o for o in re.split(r",(?![^\[]*\])", over) if o]  # commas inside [..] stay
    if args.heldout_data is not None and not args.heldout_data.is_file():
        ap.error(f"--heldout-data {args.heldout_data}: no such file")
    r = run(variants, args.seeds, args.heldout_batches, args.heldout_data)
    report(format_table(r), r, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
