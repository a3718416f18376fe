# Scratch probe of session 27 (not part of the package; inputs: benchmarks/results/partial_pours_s27_goal06.json, the
# shipped source data and session 26's 200-trajectory run under /work/runs/s26_200traj: edit RUN). Run from the
# repo root with PYTHONPATH=.
"""The band's labels: by place and tilt in the take-apart, in the methods' own data, and the model's predicted spill."""
import json

import numpy as np
import torch

from active.experiment import ExperimentConfig
from active.io import load_torch
from active.loop import planning_dynamics
from active.run import compose_config
from dynamics.data import Transitions
from sim.world import WorldConfig
from task import state_distance

RUN = "/work/runs/s26_200traj"
r = json.load(open("benchmarks/results/partial_pours_s27_goal06.json"))
P = r["pours"]


def share(p):
    return p["jitter_share_good"]


rec = np.array([p["label_recorded"] for p in P])
print(f"== as recorded: {len(P)} pours, label median {np.median(rec):.3f}, share under d_max {np.mean(rec < 0.07):.2f}")
print("== by place (good under every plant pose / all)")
for name, sel in (("x <= 0.30", lambda p: p["x"] <= 0.305),
                  ("band x 0.31-0.34, y < 0.22", lambda p: 0.305 <= p["x"] <= 0.345 and p["y"] < 0.215),
                  ("x 0.31-0.34, y >= 0.22", lambda p: 0.305 <= p["x"] <= 0.345 and p["y"] >= 0.215)):
    S = [p for p in P if sel(p)]
    print(f"  {name}: {sum(share(p) == 1 for p in S)} / {len(S)}")

print("== source-world labels from rest, pours from x <= 0.34 m, by tilt (mean + 2 std, share > d_max)")
inner = [p for p in P if p["x"] <= 0.345]
for lo, hi in ((1.0, 1.15), (1.15, 1.25), (1.25, 1.5)):
    v = np.array([u for p in inner if lo <= p["theta"] < hi for u in p["labels_source"] if u == u])
    print(f"  tilt {lo}-{hi}: n {len(v)} median {np.median(v):.3f} mean+2std {v.mean() + 2 * v.std():.3f} >d_max {np.mean(v > 0.07):.2f}")
G = np.array([u for p in inner if share(p) == 1 for u in p["labels_jitter"][1:] if u == u])
print(f"  always-good pours, target-world labels under 8 poses: mean+2std {G.mean() + 2 * G.std():.3f}")
hi_tilt = [p for p in inner if p["theta"] >= 1.25]
split = [abs(p["model"][4] - np.mean([f[4] for f in p["source"] if f is not None])) for p in hi_tilt]
print(f"  tilt >= 1.25: {sum(e > 0.03 for e in split)} of {len(hi_tilt)} off by > 0.03 in the target cup (max {max(split):.3f})")

print("== the methods' full-cup pours in the band at tilt 1.0-1.25 (3 seeds)")
for m in ("active_balanced", "random_plan"):
    Y = []
    for seed in (0, 1, 2):
        d = load_torch(f"{RUN}/seed{seed}/{m}/dataset.pt")
        X, y = d["X"].numpy(), d["y"].numpy()
        sel = ((X[:, 5] == 1) & (X[:, 3] > 0.95) & (X[:, 0] >= 0.305) & (X[:, 0] <= 0.345) & (X[:, 1] < 0.215)
               & (X[:, 6] >= 1.0) & (X[:, 6] < 1.25))
        Y.append(y[sel])
        band = (X[:, 5] == 1) & (X[:, 3] > 0.5) & (X[:, 0] >= 0.305) & (X[:, 0] <= 0.345) & (X[:, 1] < 0.215)
        print(f"  {m} seed {seed}: full-cup pours from the band, any tilt: {band.sum()}, good "
              f"{np.mean(y[band] < 0.07):.2f}, median label {np.median(y[band]):.3f}")
    Y = np.concatenate(Y)
    print(f"  {m}: n {len(Y)} median {np.median(Y):.3f} mean+2std {Y.mean() + 2 * Y.std():.3f} >d_max {np.mean(Y > 0.07):.3f}")

print("== the model's predicted spill on the shipped source data's spill-free partial full-cup pours")
cfg = compose_config([])
exp, world = ExperimentConfig.from_mapping(cfg["experiment"]), WorldConfig.from_mapping(cfg["world"])
dyn = planning_dynamics(cfg["dynamics"], cfg["world"], world, exp)
A = Transitions.load(next(__import__("pathlib").Path("dynamics/shipped").glob("source-*.pt"))).arrays()
s, a, s2 = A["s"], A["a"], A["s_next"]
with torch.no_grad():
    pred = dyn.predict(torch.as_tensor(s, dtype=torch.float32), torch.as_tensor(a, dtype=torch.float32)).double().numpy()
partial = (a[:, 0] == 1) & (s[:, 3] > 0.95) & (s2[:, 4] - s[:, 4] > 0.15) & (s2[:, 3] > 0.2)
clean = partial & (1 - s2[:, 3] - s2[:, 4] < 0.005)
fix = pred.copy()
fix[:, 4] = 1 - fix[:, 3]  # the predicted spill moved into the target cup
lab, lab_fix = state_distance(pred, s2), state_distance(fix, s2)
print(f"  {clean.sum()} of {partial.sum()} spill-free; predicted spill median {np.median(1 - pred[clean, 3] - pred[clean, 4]):.4f}; "
      f"labels mean+2std {lab[clean].mean() + 2 * lab[clean].std():.3f} -> {lab_fix[clean].mean() + 2 * lab_fix[clean].std():.3f}")

print("== in sample: the saved round-20 MDE's noise std at the band's full-cup pours (active_balanced, seed 0), by tilt")
import mde  # noqa: E402

d = load_torch(f"{RUN}/seed0/active_balanced/dataset.pt")
X, y = d["X"], d["y"].numpy()
Xn = X.numpy()
band = (Xn[:, 5] == 1) & (Xn[:, 3] > 0.5) & (Xn[:, 0] >= 0.305) & (Xn[:, 0] <= 0.345) & (Xn[:, 1] < 0.215)
M = mde.load(f"{RUN}/seed0/active_balanced/mde_iter020.pt")
noise = M.noise_std(X[band]).double().numpy()
th, yb = Xn[band, 6], y[band]
for lo, hi in ((0.0, 0.6), (0.6, 1.0), (1.0, 1.33)):
    m = (th >= lo) & (th < hi)
    print(f"  tilt {lo}-{hi}: n {m.sum()} noise std {noise[m].min():.3f}-{noise[m].max():.3f} (median {np.median(noise[m]):.3f}); "
          f"labels {yb[m].min():.3f}-{yb[m].max():.3f}")
