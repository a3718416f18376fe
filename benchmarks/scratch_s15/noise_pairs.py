import numpy as np, warnings
warnings.filterwarnings("ignore")
from dynamics.data import Transitions
ts = [Transitions.load(p) for p in ("/work/main/.cache/dynamics/data-cddfb0aa9e5a637a/dataset.pt", "/work/main/.cache/dynamics/data-85e082618221f00b/dataset.pt")]
s = np.concatenate([t.s for t in ts]); a = np.concatenate([t.a for t in ts]); s2 = np.concatenate([t.s_next for t in ts])
P = (a[:, 0] == 1) & (s[:, 3] > 0.99) & (np.abs(s2[:, 2]) < 0.05)
s, a, s2 = s[P], a[P], s2[P]
dvt = s2[:, 4] - s[:, 4]
print("full-cup pours", len(s))
for dth in (0.002, 0.005, 0.01):
    diffs = []; slopes = []
    for i in range(len(s)):
        j = np.flatnonzero((np.abs(s[:, 0] - s[i, 0]) < 1e-4) & (np.abs(s[:, 1] - s[i, 1]) < 1e-4) & (np.abs(a[:, 1] - a[i, 1]) < dth) & (np.abs(a[:, 1] - a[i, 1]) > 1e-9) & (np.arange(len(s)) > i))
        for k in j:
            if max(abs(dvt[i]), abs(dvt[k])) < 0.02: continue
            diffs.append(dvt[i] - dvt[k])
    diffs = np.array(diffs)
    mv = np.abs(diffs) >= 0
    print(f"|dtheta|<{dth}: pairs {len(diffs)}  std of diff/sqrt2 = {diffs.std()/np.sqrt(2):.4f}  mean abs diff/sqrt2 {np.abs(diffs).mean()/np.sqrt(2):.4f}  median abs diff {np.median(np.abs(diffs)):.4f}")
