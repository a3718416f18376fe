"""Session 32: the diagnostics quoted in BENCHMARKS.md "Session 32" on a quick-experiment run directory.

    PYTHONPATH=. python benchmarks/scratch_s32/fit_diagnostics.py RUN_DIR [OTHER_RUN_DIR]

1. per MDE fit (seed, method, iteration): whether the move GP's lengthscale on a volume fraction (v_ctrl, v_tgt)
   collapsed below 0.05, against that round's test plans-found rate;
2. per method and round, the MDE's noise std and latent std (outputscale) per skill, means over seeds;
3. with OTHER_RUN_DIR (the same seeds, active_balanced under another acquisition): how many training choices
   executed the same trajectory (same category, steps and spill) in both runs.
"""

import csv
import glob
import sys
import warnings

import numpy as np

import mde

warnings.filterwarnings("ignore")
run = sys.argv[1]
seeds = sorted(int(p.split("seed")[-1]) for p in glob.glob(f"{run}/seed*"))
methods = ["active_balanced", "random_plan"]
rows = []
for s in seeds:
    for m in methods:
        res = {int(r["iteration"]): r for r in csv.DictReader(open(f"{run}/seed{s}/{m}/results.csv"))}
        for it in sorted(res):
            g = mde.load(f"{run}/seed{s}/{m}/mde_iter{it:03d}.pt")
            fits = {k: sub._fitted for k, sub in g.groups.items()}
            rows.append({"seed": s, "method": m, "it": it, "found": float(res[it]["test_plan_found"]), "fits": fits})
collapsed = np.array([min(r["fits"][0.0].mean_model.covar_module.base_kernel.lengthscale.detach().ravel()[[3, 4]])
                      < 0.05 for r in rows])
found = np.array([r["found"] for r in rows])
print(f"1. move-GP volume lengthscale < 0.05 in {collapsed.mean():.2f} of {len(rows)} fits; plans found "
      f"{found[collapsed].mean():.2f} with, {found[~collapsed].mean():.2f} without")
for m in methods:
    print("   ", m, "collapsed fits at round 1:", sum(c for c, r in zip(collapsed, rows) if r["method"] == m and r["it"] == 1))
print("2. method round | skill: noise std, latent std (label units, means over seeds)")
for m in methods:
    for it in sorted({r["it"] for r in rows}):
        out = []
        for k, name in ((0.0, "move"), (1.0, "pour")):
            fs = [r["fits"][k] for r in rows if r["method"] == m and r["it"] == it]
            noise = np.mean([np.sqrt(f.const_noise_z) * f.sigma_z for f in fs])
            latent = np.mean([np.sqrt(float(f.mean_model.covar_module.outputscale)) * f.sigma_z for f in fs])
            out.append(f"{name} {noise:.3f} {latent:.3f}")
        print("  ", m, it, " | ".join(out))
if len(sys.argv) > 2:
    same = total = 0
    key = lambda r: (r["category"], r["steps"], r["final_spill"])  # noqa: E731
    for s in seeds:
        a = list(csv.DictReader(open(f"{run}/seed{s}/active_balanced/categories.csv")))
        b = list(csv.DictReader(open(f"{sys.argv[2]}/seed{s}/active_balanced/categories.csv")))
        same += sum(key(x) == key(y) for x, y in zip(a, b))
        total += min(len(a), len(b))
    print(f"3. the same trajectory in {same} of {total} choices")
