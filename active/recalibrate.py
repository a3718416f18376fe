"""Recompute the calibration rows of finished runs from their MDE checkpoints.

A run's ``calibration.csv`` (coverage of the MDE's intervals on held-out target-world transitions) is
written as the run goes. When its definition changes (rows made before ``coverage95_raw`` existed compared
with the raw labels, not with the labels as the MDE fits them), this rebuilds the rows of every iteration
whose checkpoint ``mde_iterNNN.pt`` is still there, with the run's own calibration set, and leaves the
others as they are (their raw figures moved to the ``_raw`` columns). Nothing else of the run changes.

    python -m active.recalibrate results/paper/run outputs/quick

Each seed directory is locked while it is rewritten (one writer per run directory), and ``state.pt``
and ``calibration.csv`` are replaced atomically.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence

from .io import load_torch, save_torch, write_csv
from .loop import CALIBRATION_FIELDS, calibration_row, legacy_calibration_row


def recalibrate_method(method_dir: Path, calibration: dict) -> tuple[int, int]:
    """Rebuild ``method_dir``'s calibration rows; returns (rows recomputed, rows kept as they were)."""
    from mde import load as load_mde

    state_path = method_dir / "state.pt"
    state = load_torch(state_path)
    rows, done, kept = [], 0, 0
    for row in state["calibration"]:
        ckpt = method_dir / f"mde_iter{int(row['iteration']):03d}.pt"
        if ckpt.exists():
            rows.append(calibration_row(load_mde(ckpt), calibration["X"], calibration["y"], row["method"],
                                        row["seed"], int(row["iteration"])))
            done += 1
        else:
            rows.append(legacy_calibration_row(row))
            kept += 1
    state["calibration"] = rows
    write_csv(method_dir / "calibration.csv", rows, CALIBRATION_FIELDS)
    save_torch(state_path, state)
    return done, kept


def recalibrate(run_dir: Path) -> list[tuple[Path, int, int]]:
    """Every method run below ``run_dir`` (a run or a folder of seeds): (method dir, recomputed, kept)."""
    from .runlock import RunLock

    seed_dirs = sorted({p.parent.parent for p in Path(run_dir).rglob("state.pt")})
    if not seed_dirs:
        raise FileNotFoundError(f"no <method>/state.pt below {run_dir}: not a run directory")
    out = []
    for d in seed_dirs:
        cal_path = d / "calibration_set.pt"
        if not cal_path.exists():
            raise FileNotFoundError(f"{cal_path} is missing: the held-out set of {d} is needed to recalibrate it")
        with RunLock(d):
            cal = load_torch(cal_path)
            for state_path in sorted(d.glob("*/state.pt")):
                out.append((state_path.parent, *recalibrate_method(state_path.parent, cal)))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m active.recalibrate", description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run directories (or folders of seed directories)")
    args = parser.parse_args(argv)
    for run in args.runs:
        for method_dir, done, kept in recalibrate(run):
            print(f"{method_dir}: {done} iteration(s) recomputed, {kept} kept (no checkpoint)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
