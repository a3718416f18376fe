import sys, warnings
import numpy as np, torch
warnings.filterwarnings("ignore")
import hydra.utils, dynamics
from active.loop import label_transitions, features
from active.run import compose_config
from sim.world import WorldConfig
cfg = compose_config(["progress=false"] + sys.argv[2:]); w = WorldConfig.from_mapping(cfg["world"])
dyn = dynamics.ContactAwareDynamics(dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False), w)
names = ["x", "y", "th", "vc", "vt", "skill", "p1", "p2"]
d = np.load(sys.argv[1]); s, a, s2 = d["s"], d["a"], d["s_next"]
y = label_transitions(dyn, s, a, s2, w.distance_weights)
m = hydra.utils.instantiate(cfg["mde"]).fit(torch.as_tensor(features(s, a)), torch.as_tensor(y))
g = m.groups[1.0]; f = g._fitted
for nm, mod in (("mean", f.mean_model), ("noise", f.noise_model)):
    k = mod.covar_module
    ls = k.base_kernel.lengthscale.detach().reshape(-1).numpy()
    print(nm, "outputscale %.3g" % float(k.outputscale), " ".join(f"{n}:{v:.3g}" for n, v in zip(names, ls)))
print("info", {k: v for k, v in f.info.items() if not isinstance(v, (list, dict))})
