"""Median predicted mean and std, and the admitted share, of each run's MDE on the good partial first pours of
the saved ceiling sets (s31): PYTHONPATH=. python benchmarks/scratch_s37/partial_pour_mu_sd.py RUN_DIR
(RUN_DIR with every mde_iterNNN.pt, e.g. the paper run before it was snapshotted)."""
import sys
import sys, numpy as np, torch
from pathlib import Path
from benchmarks.admission import labelled_set
import mde as M
RUN = sys.argv[1]
data = labelled_set([Path(f"benchmarks/ceiling_sets/s31_stuck_seed{i}.npz") for i in range(3)], [])
m = data["partial"] & data["good"]
X = data["X"][m]
print("partial good", int(m.sum()), "label mean", float(data["y"][m].mean()))
for it in (2, 4, 10, 20):
    for meth in ("active_balanced", "active_mean", "random_plan"):
        mus, sds, oks, hp = [], [], [], []
        for s in range(4):
            mde = M.load(f"{RUN}/seed{s}/{meth}/mde_iter{it:03d}.pt")
            mu, sd = (v.double().numpy() for v in mde.predict(X))
            mus.append(np.median(mu)); sds.append(np.median(sd)); oks.append(np.mean(mu + 2*sd < 0.07))
            gp = mde.model
            try:
                ls = gp.covar_module.base_kernel.lengthscale.detach().numpy().ravel() if hasattr(gp.covar_module,'base_kernel') else gp.covar_module.lengthscale.detach().numpy().ravel()
                hp.append(np.round(ls,2))
            except Exception as e:
                hp.append(str(e)[:40])
        print(it, meth, "median mu", np.round(mus,3), "median sd", np.round(sds,3), "admit", np.round(oks,2))
        if it in (4,20): print("    lengthscales", hp[0], hp[1])
