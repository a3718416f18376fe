"""Scratch (session 19): would a perfect MDE admit the model's own plans? The aleatoric floor of the precondition.

The ladder's model-only plans (same problems and seeds as its source / target rungs) are each executed
from their start in S environment slots (which differ only in the water's initial particle jitter). For
every step the S labels d(f_hat(s_t, a_t), s_t+1) give the deviation's true mean and std *for that plan's
states*; an MDE that knew them exactly (no epistemic uncertainty, the noise exactly the slots' scatter)
admits the step iff mean + beta_test * std < d_max. A plan is admitted iff all its steps are. Reported
per world: plans found, admitted by this oracle, their success rate over the slots, and the labels.

usage (repository root): PYTHONPATH=. python benchmarks/scratch_s19/oracle_admission.py --out X.json [--n 30] [--slots 16] [overrides]
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
    ap.add_argument("--worlds", nargs="+", default=["source", "target"])
    ap.add_argument("overrides", nargs="*")
    args = ap.parse_args()

    from active.experiment import ExperimentConfig
    from active.ladder import plan_all
    from active.loop import build_planner_config, derive_seed, label_transitions, planning_dynamics
    from active.run import compose_config
    from planner.pool import PlanPool
    from sim.execute import PouringExecutor
    from sim.problems import sample_problems
    from sim.world import WorldConfig

    cfg = compose_config(["experiment=quick", *args.overrides])
    exp = ExperimentConfig.from_mapping(cfg["experiment"])
    world = WorldConfig.from_mapping(cfg["world"])
    seed = int(cfg.get("seed", 0))
    dyn = planning_dynamics(cfg["dynamics"], cfg["world"], world, exp)
    executor = PouringExecutor(world)
    S = args.slots
    out = {"slots": S, "d_max": exp.d_max, "beta": exp.beta_test, "overrides": args.overrides}
    t_all = time.perf_counter()
    with PlanPool(dyn, build_planner_config(world, cfg["planner"], exp), 2) as pool:
        for wname in args.worlds:
            problems = sample_problems(world, args.n, derive_seed(seed, "ladder-problems", wname), world=wname)
            plans = plan_all(pool, None, problems, exp, seed, f"model-only-{wname}")
            found = [k for k, p in enumerate(plans) if p is not None]
            jobs = [(k, sl) for k in found for sl in range(S)]
            res = []
            for c in range(0, len(jobs), 32):
                chunk = jobs[c:c + 32]
                jit = np.array([problems[k].plant_jitter for k, _ in chunk]) * (wname == "target")
                res += executor.run(wname, np.array([problems[k].start[:3] for k, _ in chunk]),
                                    [plans[k].actions for k, _ in chunk], plant_jitter=jit,
                                    goals=[problems[k].goal for k, _ in chunk], slots=[sl for _, sl in chunk])
            rows = []
            for i, k in enumerate(found):
                rr = res[i * S:(i + 1) * S]
                steps = max(len(r.steps) for r in rr)
                per_step = []
                for t in range(steps):
                    have = [r for r in rr if len(r.steps) > t]
                    s = np.stack([r.steps[t].s for r in have])
                    a = np.stack([r.steps[t].a for r in have])
                    s2 = np.stack([r.steps[t].s_next for r in have])
                    y = label_transitions(dyn, s, a, s2, world.distance_weights)
                    per_step.append({"skill": int(round(a[0, 0])), "n": len(y), "mean": float(y.mean()),
                                     "std": float(y.std(ddof=1)) if len(y) > 1 else 0.0})
                adm = all(st["n"] == S and st["mean"] + exp.beta_test * st["std"] < exp.d_max for st in per_step)
                rows.append({"problem": k, "goal": problems[k].goal, "admitted": adm, "steps": per_step,
                             "success_rate": float(np.mean([bool(r.goal_reached) for r in rr])),
                             "final_target_std": float(np.std([r.states[-1, 4] for r in rr], ddof=1))})
            adm = [r for r in rows if r["admitted"]]
            out[wname] = {"n": args.n, "found": len(found), "oracle_admitted": len(adm),
                          "success_rate_found": float(np.mean([r["success_rate"] for r in rows])) if rows else None,
                          "success_rate_admitted": float(np.mean([r["success_rate"] for r in adm])) if adm else None,
                          "plans": rows}
            print(f"{wname}: found {len(found)}/{args.n}, oracle-admitted {len(adm)}, success over slots "
                  f"(found) {out[wname]['success_rate_found']}, (admitted) {out[wname]['success_rate_admitted']}",
                  flush=True)
            for r in rows:
                print(f"  p{r['problem']:02d} goal {r['goal']:.2f} succ {r['success_rate']:.2f} adm {r['admitted']!s:5s} "
                      + " ".join(f"{'MP'[st['skill']] if st['skill'] in (0, 1) else st['skill']}"
                                 f"{st['mean']:.3f}+-{st['std']:.3f}" for st in r["steps"]), flush=True)
    executor.close()
    out["seconds"] = time.perf_counter() - t_all
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1, default=float)


if __name__ == "__main__":
    main()
