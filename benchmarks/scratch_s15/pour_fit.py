"""How much of the pour error is the function class? Fit other regressors on the same pours."""
import sys, warnings, time
import numpy as np
warnings.filterwarnings("ignore")
from dynamics.data import Transitions
import dynamics
from active.run import compose_config
tr = Transitions.load("/work/main/.cache/dynamics/data-cddfb0aa9e5a637a/dataset.pt")
te = Transitions.load("/work/main/.cache/dynamics/data-85e082618221f00b/dataset.pt")
def xy(t):
    P = (t.a[:, 0] == 1) & (t.s[:, 3] > 0.05)
    s, a, s2 = t.s[P], t.a[P], t.s_next[P]
    X = np.c_[s[:, [0, 1, 3, 4]], a[:, 1:3]]
    # fractions of the controlled cup's water: to target, spilled
    vc = s[:, 3]
    to_t = (s2[:, 4] - s[:, 4]) / vc
    spill = ((1 - s2[:, 3] - s2[:, 4]) - (1 - s[:, 3] - s[:, 4])) / vc
    stuck = np.abs(s2[:, 2]) > 0.05
    return X, np.c_[to_t, spill], s, s2, stuck
Xtr, Ytr, str_, s2tr, sttr = xy(tr); Xte, Yte, ste, s2te, stte = xy(te)
print("train pours", len(Xtr), "test pours", len(Xte))
def report(name, pred_to_t, s, s2, stuck):
    vt_pred = s[:, 4] + s[:, 3] * pred_to_t
    e = np.abs(vt_pred - s2[:, 4]); mv = (np.abs(s2[:, 4] - s[:, 4]) > 0.02) & ~stuck
    return f"{name}: moved n={mv.sum()} abs err v_tgt {e[mv].mean():.4f}"
cfg = compose_config(["progress=false"])
ens = dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False)
for nm, t, (X, Y, s, s2, st) in (("train", tr, (Xtr, Ytr, str_, s2tr, sttr)), ("test", te, (Xte, Yte, ste, s2te, stte))):
    P = (t.a[:, 0] == 1) & (t.s[:, 3] > 0.05)
    p = ens.predict_np(t.s[P], t.a[P]); print(report(f"ensemble {nm}", (p[:, 4] - s[:, 4]) / s[:, 3], s, s2, st))
from sklearn.ensemble import HistGradientBoostingRegressor, ExtraTreesRegressor
from sklearn.neighbors import KNeighborsRegressor
for name, mk in (("hgb", lambda: HistGradientBoostingRegressor(max_iter=500, learning_rate=0.05)),
                 ("extratrees", lambda: ExtraTreesRegressor(300, min_samples_leaf=2, n_jobs=1)),
                 ("knn5 scaled", None)):
    t0 = time.time()
    if mk is None:
        sc = Xtr.std(0); m = KNeighborsRegressor(5, weights="distance").fit(Xtr / sc, Ytr[:, 0])
        ptr, pte = m.predict(Xtr / sc), m.predict(Xte / sc)
    else:
        m = mk().fit(Xtr, Ytr[:, 0]); ptr, pte = m.predict(Xtr), m.predict(Xte)
    print(report(name + " train", ptr, str_, s2tr, sttr), "|", report("test", pte, ste, s2te, stte), f"{time.time()-t0:.0f}s")
