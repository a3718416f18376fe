"""Scratch (session 17): the deviation labels of the transitions where a trajectory got stuck in the plant
(the last transition of a stuck_in_plant trajectory) against d_max: is a stuck move a large deviation?
python benchmarks/scratch_s17/stuck_labels.py SET.npz [SET.npz ...]"""
import sys, warnings
import numpy as np
warnings.filterwarnings("ignore")
import dynamics
from active.loop import label_transitions
from active.run import compose_config
from sim.world import WorldConfig

cfg = compose_config(["progress=false"]); w = WorldConfig.from_mapping(cfg["world"])
dyn = dynamics.ContactAwareDynamics(dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False), w)
for path in sys.argv[1:]:
    d = dict(np.load(path))
    y = label_transitions(dyn, d["s"], d["a"], d["s_next"], w.distance_weights)
    traj, cat = d["trajectory"], d["category"]
    last = np.r_[traj[1:] != traj[:-1], True]
    stuck_cat = np.isin(cat, [b"stuck_in_plant", "stuck_in_plant"])
    is_stuck_last = last & stuck_cat[traj]
    move = d["a"][:, 0] == 0
    for name, m in (("stuck move", is_stuck_last & move), ("stuck pour", is_stuck_last & ~move),
                    ("other move", ~is_stuck_last & move), ("other pour", ~is_stuck_last & ~move)):
        if m.any():
            q = np.quantile(y[m], [0.1, 0.5, 0.9])
            print(f"{path.rsplit('/', 1)[-1]} {name:10s} n {m.sum():4d}  label < d_max {np.mean(y[m] < 0.07):.2f}  "
                  f"quantiles 10/50/90 % {q.round(3)}")
