"""Homoscedastic MDE on a ceiling set: its noise std (label units) per skill against mde.label_max.
PYTHONPATH=. python benchmarks/scratch_s31/noise_vs_cap.py SET.npz [overrides]"""
import sys

import numpy as np
import torch


def main():
    from hydra.utils import instantiate

    from active.experiment import ExperimentConfig
    from active.loop import label_transitions, planning_dynamics
    from active.run import compose_config
    from planner import features
    from sim.skills import MOVE
    from sim.world import WorldConfig

    path, overrides = sys.argv[1], sys.argv[2:]
    cfg = compose_config(["progress=false", *overrides])
    exp = ExperimentConfig.from_mapping(cfg["experiment"])
    world = WorldConfig.from_mapping(cfg["world"])
    dyn = planning_dynamics(cfg["dynamics"], cfg["world"], world, exp)
    with np.load(path) as f:
        s, a, s2 = f["s"], f["a"], f["s_next"]
    y = label_transitions(dyn, s, a, s2, world.distance_weights)
    X = torch.as_tensor(features(s, a))
    for skill, name in ((MOVE, "move"), (1, "pour")):
        m = a[:, 0] == skill
        print(f"{name}: n {m.sum()}, labels > 0.07: {(y[m] > 0.07).sum()}, > 0.3: {(y[m] > 0.3).sum()}")
    for cap in (None, 0.1, 0.15, 0.2, 0.3):
        mde = instantiate({**cfg["mde"], "heteroscedastic": False, "label_max": cap}, _convert_="all")
        mde.fit(X, torch.as_tensor(y))
        mu, sd = (v.double().numpy() for v in mde.predict(X))
        row = []
        for skill, name in ((MOVE, "move"), (1, "pour")):
            m = a[:, 0] == skill
            good = m & (y < exp.d_max)
            row.append(f"{name}: sd median {np.median(sd[m]):.4f}, good admitted {np.mean((mu + 2 * sd)[good] < 0.07):.2f}")
        print(f"label_max {cap}:", " | ".join(row), flush=True)


if __name__ == "__main__":
    main()
