import numpy as np, warnings
warnings.filterwarnings("ignore")
from dynamics.data import Transitions
t = Transitions.load("/work/main/.cache/dynamics/data-cddfb0aa9e5a637a/dataset.pt"); s, a, s2 = t.s, t.a, t.s_next
mv = (a[:, 0] == 1) & (np.abs(s2[:, 4] - s[:, 4]) > 0.02) & (np.abs(s2[:, 2]) < 0.05)
spill = (1 - s2[:, 3] - s2[:, 4]) - (1 - s[:, 3] - s[:, 4])
clean = mv & (spill < 0.02)
print("moved", mv.sum(), "clean", clean.sum())
xs = np.round(s[:, 0], 2); ys = np.round(s[:, 1], 2)
print("x    : moved  clean  frac")
for x in np.unique(xs[mv]):
    m = mv & (xs == x)
    if m.sum() >= 5: print(f"{x:.2f}: {m.sum():4d} {np.sum(clean & m):4d}  {np.mean(clean[m]):.2f}")
print("y of clean pours:", np.quantile(s[clean, 1], [0, 0.1, 0.5, 0.9, 1]).round(3))
print("y of moved pours at x 0.30-0.33:", np.quantile(s[mv & (s[:,0]>0.295) & (s[:,0]<0.335), 1], [0, 0.1, 0.5, 0.9, 1]).round(3))
for yb in np.arange(0.1, 0.36, 0.04):
    m = mv & (s[:,0]>0.295) & (s[:,0]<0.335) & (s[:,1]>=yb) & (s[:,1]<yb+0.04)
    if m.sum(): print(f"  x .30-.33, y {yb:.2f}-{yb+0.04:.2f}: moved {m.sum():3d} clean frac {np.mean(clean[m]):.2f}")
print("start of all pours x:", np.quantile(s[a[:,0]==1,0],[0.1,0.5,0.9]).round(2))
