import sys, warnings
import numpy as np
warnings.filterwarnings("ignore")
import dynamics
from dynamics.data import Transitions
from active.run import compose_config
cfg = compose_config(["progress=false"])
ens = dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False)
t = Transitions.load(sys.argv[1]); s, a, s2 = t.s, t.a, t.s_next
P = (a[:, 0] == 1) & (s[:, 3] > 0.05)
preds = np.stack([m.predict_np(s[P], a[P]) for m in ens.members])
mean = preds.mean(0); err = mean[:, 4] - s2[P, 4]; ae = np.abs(err)
spread = preds[:, :, 4].std(0)
moved = np.abs(s2[P, 4] - s[P, 4]) > 0.02
later = s[P, 3] < 0.97
print("pours from non-empty cup", P.sum(), "moved", moved.sum(), "mean abs err moved", ae[moved].mean(), "bias", err[moved].mean())
for name, m in (("all", np.ones_like(moved)), ("moved", moved), ("moved later", moved & later), ("moved first", moved & ~later)):
    r = lambda x: np.argsort(np.argsort(x))
    print(name, m.sum(), "spearman(spread, abs err) = %.2f" % np.corrcoef(r(spread[m]), r(ae[m]))[0, 1])
    q = np.quantile(spread[m], [0.5, 0.75, 0.9])
    for lo, hi in zip([0, *q], [*q, 9]):
        mm = m & (spread >= lo) & (spread < hi)
        print(f"  spread [{lo:.4f},{hi:.4f}) n={mm.sum()} mean abs err {ae[mm].mean():.4f} bias {err[mm].mean():+.4f} frac abs err>0.025 {np.mean(ae[mm]>0.025):.2f}")
print("--- by angle (moved or not), pours from non-empty cup")
th = a[P, 1]; vc = s[P, 3]
for lo in np.arange(0.8, 2.3, 0.1):
    m = (th >= lo) & (th < lo + 0.1)
    if m.sum() < 5: continue
    print(f"theta {lo:.1f}-{lo+0.1:.1f} n={m.sum():4d} abs err {ae[m].mean():.4f} bias {err[m].mean():+.4f} | full cup n={np.sum(m & (vc>0.97)):4d} err {ae[m & (vc>0.97)].mean():.4f} | part n={np.sum(m & (vc<=0.97)):4d} err {ae[m & (vc<=0.97)].mean() if np.any(m & (vc<=0.97)) else float('nan'):.4f}")
# in-sample: the training data
t0 = Transitions.load(sys.argv[2]); s0, a0, s20 = t0.s, t0.a, t0.s_next
P0 = (a0[:, 0] == 1) & (s0[:, 3] > 0.05)
p0 = ens.predict_np(s0[P0], a0[P0]); e0 = np.abs(p0[:, 4] - s20[P0, 4]); mv0 = np.abs(s20[P0, 4] - s0[P0, 4]) > 0.02
print("in-sample (training data) pours that moved water: n", mv0.sum(), "abs err", e0[mv0].mean())
