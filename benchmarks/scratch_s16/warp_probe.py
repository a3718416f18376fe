"""Scratch (session 16): mu + 2 sd of plain and warped MDEs at the safe pours under the plant (session 15's map),
and the fitted pour-GP hyperparameters. python benchmarks/scratch_s16/warp_probe.py FILE.npz K [offset...]"""
import sys, warnings
import numpy as np, torch
warnings.filterwarnings("ignore")
sys.path.insert(0, __file__.rsplit("/", 1)[0])
import hydra.utils, dynamics
from active.loop import label_transitions, features
from active.ladder import ceiling_subset
from active.run import compose_config
from sim.world import WorldConfig
from warped_mde import WarpedGroupedMDE
cfg = compose_config(["progress=false"]); w = WorldConfig.from_mapping(cfg["world"])
dyn = dynamics.ContactAwareDynamics(dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False), w)
with np.load(sys.argv[1]) as f:
    d = {k: f[k] for k in f.files}
k = int(sys.argv[2]); d = ceiling_subset(d, k) if k < len(d["category"]) else d
s, a = d["s"], d["a"]; y = label_transitions(dyn, s, a, d["s_next"], w.distance_weights)
base = {kk: v for kk, v in cfg["mde"].items() if kk != "_target_"}
for c in [None] + [float(x) for x in sys.argv[3:]]:
    m = hydra.utils.instantiate(cfg["mde"]) if c is None else WarpedGroupedMDE(base, warp_offset=c)
    m.fit(torch.as_tensor(features(s, a)), torch.as_tensor(y))
    pg = m.groups[1.0]
    ls = pg._fitted.mean_model.covar_module.base_kernel.lengthscale.reshape(-1).numpy()
    nls = pg._fitted.noise_model.covar_module.base_kernel.lengthscale.reshape(-1).numpy() if pg._fitted.noise_model is not None else None
    print(f"offset {c}: pour GP ls {np.round(ls, 3)} outputscale {float(pg._fitted.mean_model.covar_module.outputscale):.3f}; noise ls {None if nls is None else np.round(nls, 3)}")
    th = np.linspace(1.1, 1.45, 8)
    for x, yy in ((0.32, 0.14), (0.34, 0.14), (0.32, 0.17), (0.30, 0.14)):
        S = np.tile([x, yy, 0, 1, 0], (len(th), 1)); A = np.c_[np.ones(len(th)), th, np.full(len(th), 0.5)]
        mu, sd = (v.double().numpy() for v in m.predict(torch.as_tensor(features(S, A))))
        print(f"  ({x:.2f},{yy:.2f}) mu+2sd: " + " ".join(f"{u+2*v:.3f}" for u, v in zip(mu, sd)))
