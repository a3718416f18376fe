"""Scratch (session 16): held-out admission (5-fold by trajectory) of the test precondition, plain vs warped MDE.
python benchmarks/scratch_s16/warp_screen.py benchmarks/results/ceiling_train_s15_512.npz 128 256 512"""
import sys, time, warnings, json
import numpy as np, torch
warnings.filterwarnings("ignore")
sys.path.insert(0, __file__.rsplit("/", 1)[0])
import hydra.utils, dynamics
from active.loop import label_transitions, features
from active.ladder import ceiling_subset
from active.run import compose_config
from mde.calibration import cross_validate
from sim.world import WorldConfig
from warped_mde import WarpedGroupedMDE

cfg = compose_config(["progress=false"]); w = WorldConfig.from_mapping(cfg["world"])
dyn = dynamics.ContactAwareDynamics(dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False), w)
path, sizes = sys.argv[1], [int(k) for k in sys.argv[2:]]
with np.load(path) as f:
    full = {k: f[k] for k in f.files}
variants = {"plain": lambda: hydra.utils.instantiate(cfg["mde"])}
for c in (0.01, 0.03, 0.1):
    variants[f"warp c={c}"] = (lambda c=c: WarpedGroupedMDE(dict((k, v) for k, v in cfg["mde"].items() if k != "_target_"), warp_offset=c))
out = []
for k in sizes:
    d = ceiling_subset(full, k) if k < len(full["category"]) else full
    s, a = d["s"], d["a"]; y = label_transitions(dyn, s, a, d["s_next"], w.distance_weights)
    X = torch.as_tensor(features(s, a)); pour = a[:, 0] == 1; good = y < 0.07
    for name, mk in variants.items():
        t0 = time.perf_counter()
        mu, sd = (v.numpy() for v in cross_validate(mk, X, torch.as_tensor(y), torch.as_tensor(d["trajectory"]), folds=5))
        ok = mu + 2 * sd < 0.07
        row = dict(k=k, variant=name, pour_good=float(ok[pour & good].mean()), pour_bad=float(ok[pour & ~good].mean()),
                   move_good=float(ok[~pour & good].mean()), move_bad=float(ok[~pour & ~good].mean()) if (~pour & ~good).any() else None,
                   n_pour_good=int((pour & good).sum()), n_pour_bad=int((pour & ~good).sum()), seconds=time.perf_counter() - t0)
        out.append(row); print(json.dumps(row), flush=True)
json.dump(out, open("/tmp/warp_screen.json", "w"), indent=1)
