"""Session 20 probe (not a benchmark): how much the shipped source data's pours spill, where a pour is clean,
and how well the default model predicts spill.

    PYTHONPATH=. python benchmarks/scratch_s20/spill_by_position.py

Spill = water that left the controlled cup and is not in the target cup (1 - v_ctrl - v_tgt). For every pour in
the shipped dataset that moved water (v_ctrl fell by > 0.02): the spill it added, the default model's prediction
of it (in sample: the model was trained on these rows), and the share of clean pours (< 0.02 added) by pour
position, binned at 2 cm relative to the target cup.
"""

import collections
import os
import warnings

import numpy as np
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import dynamics
from dynamics import shipped
from dynamics.config import DynamicsConfig, data_hash
from dynamics.data import Transitions
from sim.world import WorldConfig

warnings.filterwarnings("ignore")
with initialize_config_dir(config_dir=os.path.abspath("configs"), version_base=None):
    cfg = OmegaConf.to_container(compose("config"), resolve=True)
dc = DynamicsConfig.from_dict(cfg["dynamics"])
dh = data_hash(dc, cfg["world"])
ds = Transitions.load(shipped.find_shipped(dh), expected_hash=dh)
dyn = dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False)
s, a, sn = np.asarray(ds.s, float), np.asarray(ds.a, float), np.asarray(ds.s_next, float)
pred = np.asarray(dyn.predict_np(s, a), float)


def spill(x: np.ndarray) -> np.ndarray:
    return 1 - x[:, 3] - x[:, 4]


moved = (a[:, 0] != 0) & (s[:, 3] - sn[:, 3] > 0.02)
true_add, pred_add = spill(sn) - spill(s), spill(pred) - spill(s)
print("pours that moved water:", int(moved.sum()))
for name, m in (("all", moved), ("partial (v_ctrl after > 0.05)", moved & (sn[:, 3] > 0.05)),
                ("into the target > 0.1", moved & (sn[:, 4] - s[:, 4] > 0.1))):
    t, p = true_add[m], pred_add[m]
    print(f"{name:30s} n={m.sum():4d}  spill added: median {np.median(t):.3f}, clean (< 0.02) {np.mean(t < 0.02):.2f}"
          f"  | model: clean {np.mean(p < 0.02):.2f}, error mean {np.mean(p - t):+.4f}, mean abs {np.mean(abs(p - t)):.4f}")
clean = moved & (true_add < 0.002)
print(f"clean pours (< 0.002 added): {clean.sum()}; the model predicts median {np.median(pred_add[clean]):.4f}, "
      f"90th percentile {np.quantile(pred_add[clean], 0.9):.4f}")

tx = WorldConfig.load().target_cup.x
tab = collections.defaultdict(list)
for i, j, v in zip(np.round((s[moved, 0] - tx) / 0.02) * 0.02, np.round(s[moved, 1] / 0.02) * 0.02, true_add[moved]):
    tab[(round(i, 2) + 0.0, round(j, 2))].append(v)
print("pour position (x - target cup x, y), pours, share clean, median spill added (bins with >= 8 pours)")
for k in sorted(tab):
    v = np.array(tab[k])
    if len(v) >= 8:
        print(f"  {k[0]:+.2f} {k[1]:.2f} {len(v):4d} {np.mean(v < 0.02):.2f} {np.median(v):.3f}")
