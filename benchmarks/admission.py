"""How much of a fixed, labelled target-world set each saved MDE of a run admits, iteration by iteration:
``python -m benchmarks.admission RUN_DIR ... --sets A.npz B.npz [--out FILE] [overrides]``.

Why: the share of test problems the test planner finds plans for depends on which pours the MDE admits, and
it can fall as an MDE sees more data. This scores every ``mde_iterNNN.pt`` of the
runs with the test precondition (mu + beta_test sigma < d_max) on transitions whose true deviation is known
(saved ceiling sets, ``active.ladder --ceiling-data``; labelled with the run config's cached dynamics model):
the share of good transitions (deviation < d_max) admitted, of bad ones admitted, per skill, and for the
partial first pours (a full cup that pours part of its water into the target cup and keeps some), the pours
that goals inside the range need. Prints one row per (method, iteration), the mean over the runs' seeds;
writes JSON with every run. ``--leave-one-set-out`` (no runs): the config's MDE fitted on all sets but one and
scored on the one left out, what a ceiling-sized dataset admits (``--trajectories 8 16 32 64``: fitted on that
many of each training set, a learning curve; the column ``it/n`` is then the training trajectories in all).
``--refit 4 8 20`` (with runs): instead of the saved MDEs, the config's MDE (overrides apply, e.g.
``mde.lengthscale_max=2``) fitted on each run's own data as it stood after those iterations (``dataset.pt``, cut
at ``results.csv``'s transition counts): what another MDE would have admitted on the same data.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from benchmarks._cli import report

_MDE_FILE = re.compile(r"mde_iter(\d{3})\.pt$")


def partial_first_pours(s: np.ndarray, a: np.ndarray, s_next: np.ndarray) -> np.ndarray:
    """Mask of the pours from a (mostly) full cup that move over 0.15 of the water into the target cup and keep
    over 0.2: what every goal under the cup's capacity needs. State = (x, y, theta, fraction in the poured cup,
    fraction in the target cup)."""
    from sim.skills import POUR

    return (a[:, 0] == POUR) & (s[:, 3] > 0.5) & (s_next[:, 4] - s[:, 4] > 0.15) & (s_next[:, 3] > 0.2)


def labelled_set(paths: Sequence[Path], overrides: Sequence[str], trajectories: int | None = None) -> dict[str, Any]:
    """Features, labels and masks of the transitions of saved ceiling sets (labels from the config's model);
    ``trajectories``: only that many of each set (half random plans, half random actions)."""
    import torch

    from active.labels import label_transitions
    from active.ladder import ceiling_subset
    from active.planner_setup import planning_dynamics
    from active.run import compose_config
    from active.settings import read_settings
    from planner import features
    from sim.skills import POUR

    cfg = compose_config(list(overrides))
    settings = read_settings(cfg, method="all")
    exp, world = settings.exp, settings.world
    dyn = planning_dynamics(settings.dynamics, world, exp)
    parts = []
    for p in paths:
        if not Path(p).exists():
            raise FileNotFoundError(f"--sets {p}: no such file")
        with np.load(p) as f:
            data = {k: f[k] for k in f.files}
        parts.append(data if trajectories is None else ceiling_subset(data, trajectories))
    s, a, s2 = (np.concatenate([d[k] for d in parts]) for k in ("s", "a", "s_next"))
    y = label_transitions(dyn, s, a, s2, world.distance_weights)
    pour = a[:, 0] == POUR
    partial = partial_first_pours(s, a, s2)
    return {
        "X": torch.as_tensor(features(s, a)),
        "y": torch.as_tensor(y),
        "good": y < exp.d_max,
        "pour": pour,
        "partial": partial,
        "exp": exp,
        "n": len(y),
        "mde": cfg["mde"],
        "label_mean_partial": float(np.mean(y[partial])) if partial.any() else None,
    }


def score(mde: Any, data: dict[str, Any]) -> dict[str, float | None]:
    """Admitted shares of one MDE on the labelled set (None where a group is empty)."""
    exp, good, pour, partial = data["exp"], data["good"], data["pour"], data["partial"]
    mu, sd = (v.double().numpy() for v in mde.predict(data["X"]))
    ok = mu + exp.beta_test * sd < exp.d_max

    def share(m: np.ndarray) -> float | None:
        return float(np.mean(ok[m])) if m.any() else None

    return {
        "pour_good": share(pour & good),
        "pour_bad": share(pour & ~good),
        "move_good": share(~pour & good),
        "move_bad": share(~pour & ~good),
        "partial_good": share(partial & good),
        "partial_good_std_median": float(np.median(sd[partial & good])) if (partial & good).any() else None,
    }


def refitted(method_dir: Path, iterations: Sequence[int], mde_cfg: Any) -> list[tuple[int, Any]]:
    """The config's MDE fitted on a run's own data as it stood after each of ``iterations`` (those completed)."""
    import csv

    from hydra.utils import instantiate

    from active.io import load_torch

    data = load_torch(method_dir / "dataset.pt")
    with open(method_dir / "results.csv", newline="") as fh:
        counts = {int(r["iteration"]): int(r["n_transitions"]) for r in csv.DictReader(fh)}
    out = []
    for it in iterations:
        if it not in counts:
            continue
        n = counts[it]
        mde = instantiate(dict(mde_cfg), _convert_="all")
        mde.fit(data["X"][:n].numpy(), data["y"][:n].numpy())
        out.append((it, mde))
    return out


def run(
    run_dirs: Sequence[Path], sets: Sequence[Path], overrides: Sequence[str], refit: Sequence[int] | None = None
) -> dict[str, Any]:
    import mde as mde_pkg

    files = sorted(f for d in run_dirs for f in Path(d).glob("seed*/*/mde_iter*.pt") if _MDE_FILE.search(f.name))
    if not files:
        raise FileNotFoundError(f"no seed*/METHOD/mde_iterNNN.pt under {[str(d) for d in run_dirs]}")
    data = labelled_set(sets, overrides)
    rows = []
    if refit:
        for method_dir in sorted({f.parent for f in files}):
            base = {"run": str(method_dir.parent.parent), "seed": method_dir.parent.name, "method": method_dir.name}
            rows += [{**base, "iteration": it, **score(m, data)} for it, m in refitted(method_dir, refit, data["mde"])]
    else:
        for f in files:
            row = {
                "run": str(f.parents[2]),
                "seed": f.parents[1].name,
                "method": f.parent.name,
                "iteration": int(_MDE_FILE.search(f.name).group(1)),
            }
            rows.append({**row, **score(mde_pkg.load(f), data)})
    counts = {k: int(np.sum(data[m])) for k, m in (("pours", "pour"), ("partial_first_pours", "partial"))}
    counts.update(
        transitions=data["n"],
        pours_good=int(np.sum(data["pour"] & data["good"])),
        partial_good=int(np.sum(data["partial"] & data["good"])),
    )
    return {
        "sets": [str(p) for p in sets],
        "overrides": list(overrides),
        "refit": list(refit or []),
        "counts": counts,
        "label_mean_partial": data["label_mean_partial"],
        "rows": rows,
    }


def leave_one_set_out(
    sets: Sequence[Path], overrides: Sequence[str], sizes: Sequence[int | None] = (None,)
) -> dict[str, Any]:
    """The config's MDE fitted on all sets but one, scored on the one left out (a ceiling-sized reference);
    ``sizes``: trajectories taken from each training set (None: all), one fit per size (rows' ``iteration``:
    the training trajectories in all)."""
    from hydra.utils import instantiate

    if len(sets) < 2:
        raise ValueError(f"--leave-one-set-out needs at least 2 --sets, got {len(sets)}")
    parts = [labelled_set([p], overrides) for p in sets]
    rows = []
    for size in sizes:
        train = parts if size is None else [labelled_set([p], overrides, size) for p in sets]
        for k, held in enumerate(parts):
            rest = [d for j, d in enumerate(train) if j != k]
            mde = instantiate(dict(held["mde"]), _convert_="all")
            mde.fit(np.concatenate([d["X"].numpy() for d in rest]), np.concatenate([d["y"].numpy() for d in rest]))
            with np.load(sets[k]) as f:
                n_set = len(f["category"])
            rows.append(
                {
                    "run": "leave-one-set-out",
                    "seed": f"set{k}",
                    "method": "ceiling_mde",
                    "iteration": (n_set if size is None else size) * len(rest),
                    "held_out": str(sets[k]),
                    "partial_good_n": int(np.sum(held["partial"] & held["good"])),
                    **score(mde, held),
                }
            )
    return {
        "sets": [str(p) for p in sets],
        "overrides": list(overrides),
        "counts": {
            "transitions": sum(d["n"] for d in parts),
            "pours": sum(int(d["pour"].sum()) for d in parts),
            "pours_good": sum(int((d["pour"] & d["good"]).sum()) for d in parts),
            "partial_first_pours": sum(int(d["partial"].sum()) for d in parts),
            "partial_good": sum(int((d["partial"] & d["good"]).sum()) for d in parts),
        },
        "rows": rows,
    }


KEYS = ("pour_good", "pour_bad", "move_good", "partial_good", "partial_good_std_median")


def format_table(r: dict[str, Any]) -> str:
    c = r["counts"]
    lines = [
        f"labelled set: {c['transitions']} transitions, {c['pours']} pours ({c['pours_good']} good), "
        f"{c['partial_first_pours']} partial first pours ({c['partial_good']} good)",
        f"{'method':<16} {'it/n':>4} {'runs':>4} " + " ".join(f"{k:>23}" for k in KEYS),
    ]
    groups: dict[tuple[str, int], list[dict]] = {}
    for row in r["rows"]:
        groups.setdefault((row["method"], row["iteration"]), []).append(row)
    for (method, it), rows in sorted(groups.items()):
        cells = []
        for k in KEYS:
            v = [x[k] for x in rows if x[k] is not None]
            cells.append(f"{np.mean(v):>23.3f}" if v else f"{'-':>23}")
        lines.append(f"{method:<16} {it:>4} {len(rows):>4} " + " ".join(cells))
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.admission", description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", type=Path, nargs="*", help="run directories (seed*/METHOD/mde_iterNNN.pt below)")
    ap.add_argument("--sets", type=Path, nargs="+", required=True, help="saved ceiling sets (.npz) to score on")
    ap.add_argument("--out", type=Path, default=None, help="write the result as JSON here")
    ap.add_argument(
        "--override",
        dest="overrides",
        action="append",
        default=[],
        help="Hydra override of the config whose dynamics model labels the set (repeatable)",
    )
    ap.add_argument(
        "--leave-one-set-out",
        action="store_true",
        help="instead of runs: fit the config's MDE on all --sets but one, score the one left out",
    )
    ap.add_argument(
        "--trajectories",
        type=int,
        nargs="+",
        default=None,
        help="with --leave-one-set-out: fit on this many trajectories of each training set (one fit each)",
    )
    ap.add_argument(
        "--refit",
        type=int,
        nargs="+",
        default=None,
        help="with runs: fit the config's MDE on each run's data after these iterations instead of "
        "scoring its saved MDEs",
    )
    args = ap.parse_args(argv)
    if args.refit and (args.leave_one_set_out or not args.runs):
        ap.error("--refit goes with run directories, not --leave-one-set-out")
    if args.trajectories and not args.leave_one_set_out:
        ap.error("--trajectories goes with --leave-one-set-out")
    if args.leave_one_set_out:
        r = leave_one_set_out(args.sets, args.overrides, args.trajectories or (None,))
    elif not args.runs:
        ap.error("give run directories, or --leave-one-set-out")
    else:
        r = run(args.runs, args.sets, args.overrides, args.refit)
    report(format_table(r), r, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
