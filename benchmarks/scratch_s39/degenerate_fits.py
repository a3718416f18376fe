"""Session 39: how often a run's MDE fits sit on a degenerate optimum, and what the test planner found then.

    PYTHONPATH=. python benchmarks/scratch_s39/degenerate_fits.py NAME=RUN_DIR:METHOD[:ROUNDS] ...

A fit is degenerate when a skill's GP has its noise on the floor (< 2e-4 of the z-scored label variance) or a
lengthscale below 1e-3 of its input's range over the training data. Per method: the share of degenerate fits,
plans found in rounds with and without one, and the rounds whose test planner found plans for under half the
problems (the "volatile" rounds of BENCHMARKS.md, sessions 32 and 39). ROUNDS: the first ROUNDS rounds (all).
Folders without MDE checkpoints (results/quick/csv) give the plans-found figures alone.
"""

import csv
import glob
import os
import sys
import warnings

import numpy as np

import mde

warnings.filterwarnings("ignore")


def degenerate(path: str) -> bool | None:
    """None where the run kept no checkpoint of that round (the committed CSV folders)."""
    if not os.path.exists(path):
        return None
    for sub in mde.load(path).groups.values():
        gp = sub._fitted.mean_model
        Xt = gp.train_inputs[0]
        span = Xt.max(0).values - Xt.min(0).values
        rel = (gp.covar_module.base_kernel.lengthscale.detach().ravel() / span.clamp_min(1e-12))[span > 0]
        if float(gp.likelihood.noise) < 2e-4 or float(rel.min()) < 1e-3:
            return True
    return False


for arg in sys.argv[1:]:
    name, spec = arg.split("=", 1)
    run, method, *rounds = spec.split(":")
    deg, found = [], []
    for res_path in sorted(glob.glob(f"{run}/seed*/{method}/results.csv")):
        res = {int(r["iteration"]): float(r["test_plan_found"]) for r in csv.DictReader(open(res_path))}
        for it in sorted(res)[: int(rounds[0]) if rounds else None]:
            deg.append(degenerate(res_path.replace("results.csv", f"mde_iter{it:03d}.pt")))
            found.append(res[it])
    found = np.array(found)
    head = f"{name}: {len(found)} rounds"
    if None not in deg:
        deg = np.array(deg, dtype=bool)
        with_ = f"{found[deg].mean():.2f}" if deg.any() else "-"
        without = f"{found[~deg].mean():.2f}" if (~deg).any() else "-"
        head += f", degenerate fits {deg.mean():.2f}; plans found with {with_}, without {without}"
    print(f"{head}; plans found {found.mean():.2f}; "
          f"rounds finding plans for < 0.5 of the problems: {(found < 0.5).sum()} ({(found < 0.5).mean():.2f})")
