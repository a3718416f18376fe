"""Session 21 probe (not a benchmark): why the model's own source-world plans fail, slot by slot.

The ladder's source rung (same problems, seeds and model) plans with the model alone; every found plan is
executed from its start in S environment slots (only the water's initial particle sampling differs). Per plan:
its success rate over the slots, the final target fraction's and spill's mean and spread, the model's
predicted final state, and what failed (spill over the limit, outside the goal band, or both).
Answers session 20's open question: how much of the spill that fails plans is the pours' scatter between
slots, and how much is the model's bias.

    PYTHONPATH=. python benchmarks/scratch_s21/plan_slots.py --out X.json [--slots 16] [overrides]
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--slots", type=int, default=16)
    ap.add_argument("overrides", nargs="*")
    args = ap.parse_args()

    from active.experiment import ExperimentConfig
    from active.ladder import plan_all
    from active.loop import build_planner_config, derive_seed, planning_dynamics
    from active.run import compose_config
    from planner.pool import PlanPool
    from sim.execute import PouringExecutor
    from sim.problems import sample_problems
    from sim.world import WorldConfig

    cfg = compose_config(["experiment=quick", *args.overrides])
    exp = ExperimentConfig.from_mapping(cfg["experiment"])
    world = WorldConfig.from_mapping(cfg["world"])
    tol, lim = world.problems["tolerance"], world.problems["max_spill"]
    seed = int(cfg.get("seed", 0))
    dyn = planning_dynamics(cfg["dynamics"], cfg["world"], world, exp)
    executor = PouringExecutor(world)
    S = args.slots
    t0 = time.perf_counter()
    with PlanPool(dyn, build_planner_config(world, cfg["planner"], exp), 2) as pool:
        problems = sample_problems(world, args.n, derive_seed(seed, "ladder-problems", "source"), world="source")
        plans = plan_all(pool, None, problems, exp, seed, "model-only-source")
    found = [k for k, p in enumerate(plans) if p is not None]
    jobs = [(k, sl) for k in found for sl in range(S)]
    res = []
    for c in range(0, len(jobs), 32):
        chunk = jobs[c:c + 32]
        res += executor.run("source", np.array([problems[k].start[:3] for k, _ in chunk]),
                            [plans[k].actions for k, _ in chunk],
                            goals=[problems[k].goal for k, _ in chunk], slots=[sl for _, sl in chunk])
    executor.close()
    rows = []
    for i, k in enumerate(found):
        rr = res[i * S:(i + 1) * S]
        fin = np.array([r.states[-1] for r in rr])
        tgt, spill = fin[:, 4], 1 - fin[:, 3] - fin[:, 4]
        g = problems[k].goal
        band, clean = abs(tgt - g) <= tol, spill <= lim
        pred = np.asarray(plans[k].states[-1], float) if getattr(plans[k], "states", None) is not None else None
        rows.append({"problem": k, "goal": g, "actions": np.asarray(plans[k].actions).tolist(),
                     "pred_final": None if pred is None else pred.tolist(),
                     "success_rate": float(np.mean(band & clean)), "band_rate": float(band.mean()),
                     "clean_rate": float(clean.mean()), "target_mean": float(tgt.mean()), "target_std": float(tgt.std(ddof=1)),
                     "spill_mean": float(spill.mean()), "spill_std": float(spill.std(ddof=1)),
                     "pours": int(np.sum(np.asarray(plans[k].actions)[:, 0] == 1))})
        r = rows[-1]
        pt = "" if pred is None else f" pred tgt {pred[4]:.3f} spill {1 - pred[3] - pred[4]:.3f}"
        print(f"p{k:02d} goal {g:.2f} pours {r['pours']} succ {r['success_rate']:.2f} band {r['band_rate']:.2f} "
              f"clean {r['clean_rate']:.2f} | tgt {r['target_mean']:.3f}+-{r['target_std']:.3f} "
              f"spill {r['spill_mean']:.3f}+-{r['spill_std']:.3f}{pt}", flush=True)
    out = {"slots": S, "n": args.n, "found": len(found), "overrides": args.overrides,
           "success_rate_found": float(np.mean([r["success_rate"] for r in rows])),
           "seconds": time.perf_counter() - t0, "plans": rows}
    print(f"found {len(found)}/{args.n}, mean success over slots {out['success_rate_found']:.2f}")
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
