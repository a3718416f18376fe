import numpy as np, warnings
warnings.filterwarnings("ignore")
import dynamics
from dynamics.data import Transitions
from active.run import compose_config
cfg = compose_config(["progress=false"])
ens = dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False)
for path in ("/work/main/.cache/dynamics/data-85e082618221f00b/dataset.pt", "/work/main/.cache/dynamics/data-cddfb0aa9e5a637a/dataset.pt"):
    t = Transitions.load(path); s, a, s2 = t.s, t.a, t.s_next
    p = ens.predict_np(s, a); e = np.abs(p[:, 4] - s2[:, 4])
    # previous action of the same trajectory
    prev = np.full(len(s), -1)
    prevlen = np.zeros(len(s))
    key = {(tr, st): i for i, (tr, st) in enumerate(zip(t.traj, t.step))}
    for i, (tr, st) in enumerate(zip(t.traj, t.step)):
        j = key.get((tr, st - 1))
        if j is not None:
            prev[i] = int(a[j, 0]); prevlen[i] = np.hypot(*(s2[j, :2] - s[j, :2]))
    mv = (a[:, 0] == 1) & (np.abs(s2[:, 4] - s[:, 4]) > 0.02) & (np.abs(s2[:, 2]) < 0.05)
    print(path.split('/')[-2])
    for name, m in (("first action", t.step == 0), ("after a move", prev == 0), ("after a pour", prev == 1)):
        mm = mv & m
        print(f"  moved pours {name:14s} n={mm.sum():4d} abs err {e[mm].mean():.4f}  full cup: n={np.sum(mm & (s[:,3]>0.99)):4d} err {e[mm & (s[:,3]>0.99)].mean():.4f}")
    for lo, hi in ((0, 0.02), (0.02, 0.08), (0.08, 0.2), (0.2, 1)):
        mm = mv & (prev == 0) & (prevlen >= lo) & (prevlen < hi) & (s[:, 3] > 0.99)
        print(f"  full-cup pour after a move of {lo:.2f}-{hi:.2f} m: n={mm.sum():4d} abs err {e[mm].mean():.4f}")
    spill_inc = (1 - s2[:, 3] - s2[:, 4]) - (1 - s[:, 3] - s[:, 4])
    pspill = (1 - p[:, 3] - p[:, 4]) - (1 - s[:, 3] - s[:, 4])
    tx = 0.0
    print("  by true spill of the pour:")
    for lo, hi in ((-1, 0.005), (0.005, 0.02), (0.02, 0.1), (0.1, 2)):
        mm = mv & (spill_inc >= lo) & (spill_inc < hi)
        print(f"   spill {lo:.3f}-{hi:.3f}: n={mm.sum():4d} abs err vtgt {e[mm].mean():.4f} bias {np.mean(p[mm,4]-s2[mm,4]):+.4f}; pred spill<0.02: {np.mean(pspill[mm]<0.02):.2f}")
    mm = mv & (pspill < 0.01)
    print(f"   model predicts spill<0.01: n={mm.sum()} abs err vtgt {e[mm].mean():.4f}; of those true spill>0.02: {np.mean(spill_inc[mm]>0.02):.2f}")
    for lo in np.arange(0.30, 0.52, 0.02):
        m2 = mm & (s[:, 0] >= lo) & (s[:, 0] < lo + 0.02)
        if m2.sum() > 5: print(f"     x {lo:.2f}: n={m2.sum():3d} abs err {e[m2].mean():.4f}")
