"""Why the ceiling's admitted plans end in the plant: for each stuck test plan, the blocked move's MDE prediction and
the training moves near it (same start and target within 2 cm). Usage:
PYTHONPATH=. python benchmarks/scratch_s31/stuck_moves.py OUT.json SETS_DIR [overrides...]"""
import json
import sys
from pathlib import Path

import numpy as np
import torch


def main():
    out, sets_dir, overrides = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3:]
    from hydra.utils import instantiate

    from active.experiment import ExperimentConfig
    from active.ladder import execute_plans, plan_all
    from active.loop import build_planner_config, derive_seed, label_transitions, planning_dynamics
    from active.run import compose_config
    from planner import features
    from planner.pool import PlanPool
    from sim.execute import PouringExecutor
    from sim.problems import sample_problems
    from sim.skills import MOVE
    from sim.world import WorldConfig

    cfg = compose_config(["progress=false", "planner.workers=1", *overrides])
    exp = ExperimentConfig.from_mapping(cfg["experiment"])
    world = WorldConfig.from_mapping(cfg["world"])
    dyn = planning_dynamics(cfg["dynamics"], cfg["world"], world, exp)
    executor = PouringExecutor(world)
    rows = []
    with PlanPool(dyn, build_planner_config(world, cfg["planner"], exp), 1) as pool:
        for seed in (0, 1, 2):
            with np.load(sets_dir / f"ceiling_train_seed{seed}.npz") as f:
                data = {k: f[k] for k in f.files}
            s, a, s2 = data["s"], data["a"], data["s_next"]
            y = label_transitions(dyn, s, a, s2, world.distance_weights)
            mde = instantiate(dict(cfg["mde"]), _convert_="all").fit(torch.as_tensor(features(s, a)), torch.as_tensor(y))
            test = sample_problems(world, 30, derive_seed(seed, "ladder-ceiling-test"), world="target")
            plans = plan_all(pool, mde, test, exp, seed, "ceiling-test")
            res = execute_plans(executor, "target", test, plans)
            mv = a[:, 0] == MOVE
            for k, r in enumerate(res):
                if r is None or r.category != "stuck_in_plant":
                    continue
                i = next((j for j, st in enumerate(r.steps) if st.stuck), len(r.steps) - 1)
                st = r.steps[i]
                pa = np.asarray(plans[k].actions)[i]
                X = torch.as_tensor(features(st.s[None], pa[None]))
                mu, sd = (float(v.double().numpy()[0]) for v in mde.predict(X))
                lab = float(label_transitions(dyn, st.s[None], pa[None], st.s_next[None], world.distance_weights)[0])
                near = mv & (np.abs(s[:, 0] - st.s[0]) < 0.02) & (np.abs(s[:, 1] - st.s[1]) < 0.02) \
                    & (np.abs(a[:, 1] - pa[1]) < 0.02) & (np.abs(a[:, 2] - pa[2]) < 0.02)
                near_end = mv & (np.abs(a[:, 1] - pa[1]) < 0.02) & (np.abs(a[:, 2] - pa[2]) < 0.02)
                rows.append({"set": seed, "problem": k, "step": i, "skill": int(pa[0]), "s": st.s[:3].round(3).tolist(),
                             "a": pa.round(3).tolist(), "s_next": st.s_next[:3].round(3).tolist(),
                             "plant_jitter": np.asarray(test[k].plant_jitter).round(4).tolist(),
                             "label": round(lab, 4), "mu": round(mu, 4), "sd": round(sd, 4),
                             "near_n": int(near.sum()), "near_labels": np.round(y[near], 3).tolist(),
                             "near_end_n": int(near_end.sum()),
                             "near_end_bad": int((y[near_end] > exp.d_max).sum())})
                print(rows[-1], flush=True)
            bad = mv & (y > exp.d_max)
            print(f"set {seed}: training moves {int(mv.sum())}, bad {int(bad.sum())}; bad move targets:",
                  np.round(a[bad, 1:], 2).tolist(), "starts:", np.round(s[bad, :2], 2).tolist(), flush=True)
    executor.close()
    out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
