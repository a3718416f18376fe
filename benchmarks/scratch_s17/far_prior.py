"""Scratch (session 17): in every iteration of a run directory, each skill GP's latent mu + 2 sigma far from
its data (2 sqrt(outputscale) x label std; the prior mean is zero deviation) against that iteration's test.
python benchmarks/scratch_s17/far_prior.py RUN_DIR [d_max]"""
import csv, json, sys
from pathlib import Path
import numpy as np
from mde import GroupedMDE

d_max = float(sys.argv[2]) if len(sys.argv) > 2 else 0.07
rows = []
for f in sorted(Path(sys.argv[1]).glob("seed*/*/mde_iter*.pt")):
    it = int(f.stem[-3:])
    res = {int(r["iteration"]): r for r in csv.DictReader(open(f.parent / "results.csv"))}[it]
    g = GroupedMDE.load(f); far = {}
    for key, name in ((0.0, "move"), (1.0, "pour")):
        c = g.groups.get(key)
        if c is None or not c.is_fitted:
            far[name] = None
            continue
        fit = c._fitted
        far[name] = 2 * float(fit.mean_model.covar_module.outputscale) ** 0.5 * fit.sigma_z
    rows.append(dict(seed=f.parent.parent.name, method=f.parent.name, iteration=it, far_move=far["move"],
                     far_pour=far["pour"], found=float(res["test_plan_found"]), success=float(res["test_success"])))
open_ = lambda r, k: r[k] is not None and r[k] < d_max  # noqa: E731
for it in sorted({r["iteration"] for r in rows}):
    rs = [r for r in rows if r["iteration"] == it]
    print(f"iter {it}: runs {len(rs)}, pour GP open far from data {sum(open_(r, 'far_pour') for r in rs)}, "
          f"move GP open {sum(open_(r, 'far_move') for r in rs)}")
a = [r for r in rows if open_(r, "far_pour") or open_(r, "far_move")]
b = [r for r in rows if r not in a]
for name, rs in (("a GP open far from data", a), ("neither open", b)):
    if rs:
        print(f"{name}: {len(rs)} run-iterations, test found {np.mean([r['found'] for r in rs]):.3f}, "
              f"success {np.mean([r['success'] for r in rs]):.3f}")
json.dump(rows, open(Path(sys.argv[1]) / "far_prior.json", "w"), indent=1)
