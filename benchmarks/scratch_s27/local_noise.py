# Scratch probe of session 27 (not part of the package; inputs: session 26 ceiling sets under /work/runs/s26_ceil06 and
# the 200-trajectory run under /work/runs/s26_200traj: edit the paths). Run from the repo root with PYTHONPATH=.
"""Scratch probe: would a local (k-nearest-neighbour) noise estimate open the precondition on the band's partial
pours without admitting bad pours? Leave one ceiling set out; the default MDE's mean and latent variance, the
noise replaced by the mean squared residual of the k nearest training pours (scaled distance)."""
import sys, json
import numpy as np, torch
from hydra.utils import instantiate
from benchmarks.admission import labelled_set
from pathlib import Path
sets = [Path(f"/work/runs/s26_ceil06/ceiling_train_seed{k}.npz") for k in (0, 1, 2)]
ov = ["world.problems.goal=[0.3,0.6]"]
parts = [labelled_set([p], ov) for p in sets]
# features: x y th_cup f_src f_tgt skill theta hold
SCALE = np.array([0.01, 0.01, 1.0, 0.1, 0.1, 1.0, 0.05, 0.3])
rows = []
for k, held in enumerate(parts):
    rest = [d for j, d in enumerate(parts) if j != k]
    Xtr = np.concatenate([d["X"].numpy() for d in rest]); ytr = np.concatenate([d["y"].numpy() for d in rest])
    m = instantiate(dict(held["mde"]), _convert_="all"); m.fit(Xtr, ytr)
    Xte = held["X"].numpy(); exp = held["exp"]
    mu, var_lat = (v.double().numpy() for v in m.mean_var(torch.tensor(Xte), observation_noise=False))
    mu_d, sd_d = (v.double().numpy() for v in m.predict(torch.tensor(Xte)))
    mu_tr = m.predict(torch.tensor(Xtr))[0].double().numpy()
    res2 = (ytr - mu_tr) ** 2
    ptr = Xtr[:, 5] == 1
    out = {"set": k}
    for K in (4, 8, 16):
        sd_loc = np.array(sd_d)
        mu_knn = np.array(mu_d); sd_knn = np.array(sd_d)
        for i in np.flatnonzero(Xte[:, 5] == 1):
            dist = np.sqrt((((Xtr[ptr] - Xte[i]) / SCALE) ** 2).sum(1))
            nn = np.argsort(dist)[:K]
            sd_loc[i] = np.sqrt(var_lat[i] + res2[ptr][nn].mean())
            mu_knn[i] = ytr[ptr][nn].mean(); sd_knn[i] = np.sqrt(ytr[ptr][nn].var() * K / (K - 1))
        for name, mu_, sd_ in (("default", mu_d, sd_d), (f"gp_mean+knn_noise_k{K}", mu, sd_loc), (f"knn_mean+knn_std_k{K}", mu_knn, sd_knn)):
            ok = mu_ + exp.beta_test * sd_ < exp.d_max
            g, pr, pa = held["good"], held["pour"], held["partial"]
            out[name] = {"pour_good": float(ok[pr & g].mean()), "pour_bad": float(ok[pr & ~g].mean()),
                         "partial_good": float(ok[pa & g].mean()), "partial_bad": float(ok[pa & ~g].mean()) if (pa & ~g).any() else None}
    rows.append(out)
    print(json.dumps(out, indent=None), flush=True)
keys = [k for k in rows[0] if k != "set"]
print("\nmean over the three held-out sets: pour good / pour bad / partial good / partial bad")
for key in keys:
    v = [[r[key][c] for r in rows if r[key][c] is not None] for c in ("pour_good", "pour_bad", "partial_good", "partial_bad")]
    print(f"{key:28s} " + " ".join(f"{np.mean(x):.3f}" for x in v))
