"""Session 21 probe (not a benchmark): does a viscous liquid spill less on today's default world?

Session 3 measured viscosity on a world that no longer exists (ppc 4, no ghost wall mass, half the water) and
only on one pour. Today the source rung's failures are spills (session 20: 12 % of the shipped data's pours that
move water add < 0.02 spill). This executes the same random source-world sequences (the data generator's first
``--batches`` batches, same seeds) at each viscosity and reports, over the pours that moved water: the share
that added < 0.02 spill, the median spill added, and the share of partial pours.

    PYTHONPATH=. python benchmarks/scratch_s21/viscosity_spill.py --out X.json --viscosity 0 3 10 [--batches 2]
"""
from __future__ import annotations

import argparse
import json
import os
import time
import warnings

import numpy as np


def stats(tr) -> dict:
    s, a, sn = np.asarray(tr.s, float), np.asarray(tr.a, float), np.asarray(tr.s_next, float)
    spill_add = (1 - sn[:, 3] - sn[:, 4]) - (1 - s[:, 3] - s[:, 4])
    moved = (a[:, 0] != 0) & (s[:, 3] - sn[:, 3] > 0.02)
    into = moved & (sn[:, 4] - s[:, 4] > 0.1)
    partial = moved & (sn[:, 3] > 0.05)
    return {"transitions": len(s), "pours_moved": int(moved.sum()),
            "clean_share": float(np.mean(spill_add[moved] < 0.02)),
            "median_spill_added": float(np.median(spill_add[moved])),
            "clean_share_into_target": float(np.mean(spill_add[into] < 0.02)) if into.any() else None,
            "pours_into_target": int(into.sum()),
            "partial_share": float(np.mean(partial[moved])),
            "clean_partial": int((partial & (spill_add < 0.02)).sum())}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--viscosity", type=float, nargs="+", default=[0.0, 3.0, 10.0])
    ap.add_argument("--batches", type=int, default=2)
    args = ap.parse_args()
    warnings.filterwarnings("ignore")
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from dynamics.config import DynamicsConfig
    from dynamics.data import generate_transitions

    with initialize_config_dir(config_dir=os.path.abspath("configs"), version_base=None):
        cfg = OmegaConf.to_container(compose("config"), resolve=True)
    dc = DynamicsConfig.from_dict(cfg["dynamics"])
    out = {"batches": args.batches, "rows": []}
    for mu in args.viscosity:
        w = json.loads(json.dumps(cfg["world"]))
        w["sim"]["viscosity"] = mu
        t0 = time.perf_counter()
        tr = generate_transitions(dc.data, "source", n_batches=args.batches, world_cfg=w, progress=False)
        row = {"viscosity": mu, "seconds": time.perf_counter() - t0, **stats(tr)}
        out["rows"].append(row)
        print(json.dumps(row), flush=True)
        with open(args.out, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
