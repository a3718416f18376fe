import sys, warnings
import numpy as np, torch
warnings.filterwarnings("ignore")
import hydra.utils, dynamics
from active.loop import label_transitions, features
from active.run import compose_config
from sim.world import WorldConfig
cfg = compose_config(["progress=false"]); w = WorldConfig.from_mapping(cfg["world"])
dyn = dynamics.ContactAwareDynamics(dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False), w)
for path in sys.argv[1:]:
    d = np.load(path); s, a, s2 = d["s"], d["a"], d["s_next"]
    y = label_transitions(dyn, s, a, s2, w.distance_weights)
    m = hydra.utils.instantiate(cfg["mde"]).fit(torch.as_tensor(features(s, a)), torch.as_tensor(y))
    print(path)
    th = np.linspace(1.1, 1.45, 8)
    for x, yy in ((0.32, 0.14), (0.33, 0.14), (0.34, 0.14), (0.32, 0.17), (0.30, 0.14), (0.32, 0.11)):
        S = np.tile([x, yy, 0, 1, 0], (len(th), 1)); A = np.c_[np.ones(len(th)), th, np.full(len(th), 0.5)]
        X = torch.as_tensor(features(S, A)); mu, sd = (v.double().numpy() for v in m.predict(X)); nz = m.noise_std(X).double().numpy()
        print(f"  ({x:.2f},{yy:.2f}) mu+2sd: " + " ".join(f"{u+2*v:.3f}" for u, v in zip(mu, sd)) + "  | noise sd " + " ".join(f"{v:.3f}" for v in nz))
    near = (a[:, 0] == 1) & (np.abs(s[:, 0] - 0.325) < 0.016) & (np.abs(s[:, 1] - 0.14) < 0.016) & (s[:, 3] > 0.5)
    print("  training pours within (0.31-0.34, 0.13-0.15), cup > half full:", int(near.sum()), "labels", np.round(np.sort(y[near]), 3)[:20])
