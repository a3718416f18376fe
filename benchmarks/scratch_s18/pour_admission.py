"""Scratch (session 18): on a saved ceiling set, the fitted MDE's test precondition (mu + 2 sigma < d_max) on
the set's own real pours into the target cup (>= 0.1 of the water moved, spill <= 0.02) and on the moves
that led to them. usage: python pour_admission.py SET.npz [hydra overrides]"""
import sys

import numpy as np
import torch
from hydra.utils import instantiate

import dynamics
from active.loop import label_transitions
from active.run import compose_config
from planner import features
from sim.world import WorldConfig

cfg = compose_config(sys.argv[2:])
world = WorldConfig.from_mapping(cfg["world"])
dyn = dynamics.ContactAwareDynamics(dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False), world)
d = dict(np.load(sys.argv[1]))
s, a, s2 = d["s"], d["a"], d["s_next"]
y = label_transitions(dyn, s, a, s2, world.distance_weights)
X = torch.as_tensor(features(s, a))
mde = instantiate(dict(cfg["mde"]), _convert_="all").fit(X, torch.as_tensor(y))
mu, sd = (v.double().numpy() for v in mde.predict(X))
ok = mu + 2 * sd < 0.07
nz = mde.noise_std(X).double().numpy()
pour = a[:, 0] == 1
into = pour & (s2[:, 4] - s[:, 4] > 0.1) & (1 - s2[:, 3] - s2[:, 4] <= 0.02)
print(f"pours into the target cup: {into.sum()} of {pour.sum()} pours; admitted {ok[into].sum()}")
for i in np.flatnonzero(into):
    pm = i - 1 if i > 0 and d["trajectory"][i - 1] == d["trajectory"][i] else None
    mv = "" if pm is None else f" | preceding move lbl {y[pm]:.3f} mu {mu[pm]:.3f} sd {sd[pm]:.3f} ok {ok[pm]}"
    print(f"  xy ({s[i,0]:.2f},{s[i,1]:.2f}) vc {s[i,3]:.2f} theta {a[i,1]:.2f} hold {a[i,2]:.2f} -> vt {s2[i,4]:.2f}: "
          f"label {y[i]:.3f} mu {mu[i]:.3f} sd {sd[i]:.3f} (noise {nz[i]:.3f}) ok {ok[i]}{mv}")
for k, m in (("move", ~pour), ("pour", pour)):
    print(k, "label<0.07:", round(float((y[m] < 0.07).mean()), 2), "admitted:", round(float(ok[m].mean()), 2),
          "median sd", round(float(np.median(sd[m])), 4))
