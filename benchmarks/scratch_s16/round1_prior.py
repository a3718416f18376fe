"""Scratch (session 16): after round 1 of the paper protocol, the pour GP's far-from-data mu + 2 sigma
(2 sqrt(outputscale) x label std, the prior mean being zero deviation) against the run's test plans found.
python benchmarks/scratch_s16/round1_prior.py RUN_DIR"""
import csv, sys
import numpy as np
from pathlib import Path
from mde import GroupedMDE
rows = []
for f in sorted(Path(sys.argv[1]).glob("seed*/*/mde_iter001.pt")):
    g = GroupedMDE.load(f); c = g.groups.get(1.0)
    r = next(csv.DictReader(open(f.parent / "results.csv")))
    if c is None or not c.is_fitted:
        far, ymax, n = float("nan"), float("nan"), 0
    else:
        fit = c._fitted; far = 2 * float(fit.mean_model.covar_module.outputscale) ** 0.5 * fit.sigma_z
        ymax, n = float(fit.y.max()), len(fit.y)
    rows.append((f.parent.parent.name, f.parent.name, n, ymax, far, float(r["test_plan_found"]), float(r["test_success"])))
    print(f"{rows[-1][0]} {rows[-1][1]:16s} pours {n:2d} max label {ymax:.3f} far mu+2sd {far:.3f} test found {rows[-1][5]:.2f} success {rows[-1][6]:.2f}")
a = np.array([r[2:] for r in rows], float); open_ = a[:, 2] < 0.07
print(f"far mu+2sd < d_max in {open_.sum()} runs: mean found {a[open_, 3].mean():.2f}, success {a[open_, 4].mean():.2f}; "
      f"others: found {a[~open_, 3].mean():.2f}, success {a[~open_, 4].mean():.2f}")
