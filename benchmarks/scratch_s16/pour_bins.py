"""Scratch (session 16): ceiling-data pours by cup position: count, share with label >= d_max, median label."""
import sys, warnings
import numpy as np
warnings.filterwarnings("ignore")
import dynamics
from active.loop import label_transitions
from active.run import compose_config
from sim.world import WorldConfig
cfg = compose_config(["progress=false"]); w = WorldConfig.from_mapping(cfg["world"])
dyn = dynamics.ContactAwareDynamics(dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False), w)
with np.load(sys.argv[1]) as f:
    d = {k: f[k] for k in f.files}
s, a = d["s"], d["a"]; y = label_transitions(dyn, s, a, d["s_next"], w.distance_weights)
p = (a[:, 0] == 1) & (s[:, 3] > 0.05)   # pours of a cup that still holds water
print("pours with water:", p.sum(), "of", (a[:, 0] == 1).sum())
xb = np.arange(0.20, 0.42, 0.02); yb = np.arange(0.08, 0.32, 0.03)
print("rows: cup y bin; cols: x bin; cell = n / share bad")
print("       " + " ".join(f"{x:9.2f}" for x in xb[:-1]))
for y0, y1 in zip(yb[:-1], yb[1:]):
    cells = []
    for x0, x1 in zip(xb[:-1], xb[1:]):
        m = p & (s[:, 0] >= x0) & (s[:, 0] < x1) & (s[:, 1] >= y0) & (s[:, 1] < y1)
        cells.append(f"{m.sum():3d}/{(y[m] >= 0.07).mean() if m.any() else float('nan'):4.2f}")
    print(f"{y0:.2f}-{y1:.2f} " + " ".join(f"{c:>9}" for c in cells))
