import sys, warnings
import numpy as np
warnings.filterwarnings("ignore")
import dynamics
from active.loop import label_transitions
from active.run import compose_config
from sim.world import WorldConfig
cfg = compose_config(["progress=false"]); w = WorldConfig.from_mapping(cfg["world"])
dyn = dynamics.ContactAwareDynamics(dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False), w)
d = np.load(sys.argv[1]); s, a, s2 = d["s"], d["a"], d["s_next"]
y = label_transitions(dyn, s, a, s2, w.distance_weights)
P = (a[:, 0] == 1) & (s[:, 3] > 0.3) & (a[:, 1] > 1.0)
print("pours moving water-ish:", P.sum())
print(" x     y-bin     n  median  frac>dmax  labels")
for x in np.arange(0.24, 0.40, 0.02):
    for yb in (0.06, 0.14, 0.22, 0.30):
        m = P & (s[:, 0] >= x - 0.005) & (s[:, 0] < x + 0.015) & (s[:, 1] >= yb) & (s[:, 1] < yb + 0.08)
        if m.sum() >= 2:
            print(f"{x:.2f} {yb:.2f}-{yb+0.08:.2f} {m.sum():3d}  {np.median(y[m]):.3f}   {np.mean(y[m] > 0.07):.2f}   " + " ".join(f"{v:.2f}" for v in np.sort(y[m])[:12]))
