"""The ceiling rung's test (ladder ceiling seeds' 30 problems each, the paper's test precondition) with an MDE
fitted on the pooled training data of finished quick runs (their dataset.pt: features and labels), to ask whether
more data *of the kind the methods collect* raises test success above what each run reached; or, given one saved
MDE (a run's mde_iterNNN.pt), that MDE as it is, to put a run's own MDE on the ceiling's test problems.

    PYTHONPATH=. python benchmarks/scratch_s29/pooled_ceiling.py OUT.json RUN_DIR/seed*/active_balanced/dataset.pt ...
    PYTHONPATH=. python benchmarks/scratch_s29/pooled_ceiling.py OUT.json RUN_DIR/seed0/active_balanced/mde_iter008.pt

OVERRIDES="experiment.planner_propagation_budget=10000" (Hydra overrides, space-separated) changes the config.
"""
from __future__ import annotations

import json
import os
import sys
import time

import numpy as np
import torch
from hydra.utils import instantiate

from mde import load as mde_load

from active.experiment import ExperimentConfig
from active.ladder import ceiling_test
from active.loop import build_planner_config, planner_workers, planning_dynamics
from active.run import compose_config
from planner.pool import PlanPool
from sim.execute import PouringExecutor
from sim.world import WorldConfig


def main() -> None:
    out, files = sys.argv[1], sys.argv[2:]
    cfg = compose_config(["progress=false", "planner.workers=2", *os.environ.get("OVERRIDES", "").split()])
    exp = ExperimentConfig.from_mapping(cfg["experiment"])
    world = WorldConfig.from_mapping(cfg["world"])
    t0 = time.perf_counter()
    if len(files) == 1 and "mde_iter" in files[0]:
        mde = mde_load(files[0])
        y = mde.train_y
    else:
        X = torch.cat([torch.load(f, weights_only=False)["X"] for f in files])
        y = torch.cat([torch.load(f, weights_only=False)["y"] for f in files])
        mde = instantiate(dict(cfg["mde"]), _convert_="all").fit(X, y)
    t_fit = time.perf_counter() - t0
    print(f"MDE on {len(y)} transitions from {len(files)} file(s): {t_fit:.0f} s", flush=True)
    dyn = planning_dynamics(cfg["dynamics"], cfg["world"], world, exp, False)
    executor = PouringExecutor(world)
    rows = []
    with PlanPool(dyn, build_planner_config(world, cfg["planner"], exp), planner_workers(cfg["planner"]),
                  preload=[type(mde).__module__]) as pool:
        for seed in (0, 1, 2):
            r = ceiling_test(world, pool, mde, exp, executor, 30, seed)
            rows.append({"seed": seed, **{k: v for k, v in r.items() if k not in ("problems", "plan_seconds")}})
            print(rows[-1], flush=True)
    executor.close()
    res = {"files": files, "transitions": len(y), "fit_seconds": t_fit, "per_seed": rows,
           "found": float(np.mean([r["found"] for r in rows])), "success": float(np.mean([r["success"] for r in rows]))}
    with open(out, "w") as f:
        json.dump(res, f, indent=1, default=float)
    print("found", res["found"], "success", res["success"])


if __name__ == "__main__":
    main()
