"""Scratch: the ceiling MDE (fitted on a ceiling_train.npz) on every executed step of model-only plans."""
import json, sys
import numpy as np, torch
import hydra.utils
import dynamics
from active.experiment import ExperimentConfig
from active.ladder import execute_plans, plan_all
from active.loop import build_planner_config, derive_seed, planner_workers, label_transitions, features
from active.run import compose_config
from planner.pool import PlanPool
from sim.execute import PouringExecutor
from sim.problems import sample_problems
from sim.world import WorldConfig

if __name__ == "__main__":
    npz, out, wname = sys.argv[1], sys.argv[2], sys.argv[3]
    over = sys.argv[4:]
    cfg = compose_config(over + ["progress=false"])
    exp = ExperimentConfig.from_mapping(cfg["experiment"])
    w = WorldConfig.from_mapping(cfg["world"])
    dyn = dynamics.ContactAwareDynamics(dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False), w)
    d = np.load(npz); s, a, s2 = d["s"], d["a"], d["s_next"]
    y = label_transitions(dyn, s, a, s2, w.distance_weights)
    m = hydra.utils.instantiate(cfg["mde"]).fit(torch.as_tensor(features(s, a)), torch.as_tensor(y))
    seed = int(cfg.get("seed", 0))
    probs = sample_problems(w, 30, derive_seed(seed, "ladder-problems", wname), world=wname)
    with PlanPool(dyn, build_planner_config(w, cfg["planner"], exp), 1) as pool:
        plans = plan_all(pool, None, probs, exp, seed, f"model-only-{wname}")
    ex = PouringExecutor(w); res = execute_plans(ex, wname, probs, plans); ex.close()
    rows = []
    for k, r in enumerate(res):
        if r is None: continue
        S = np.array([st.s for st in r.steps]); A = np.array([st.a for st in r.steps]); S2 = np.array([st.s_next for st in r.steps])
        lab = label_transitions(dyn, S, A, S2, w.distance_weights)
        X = torch.as_tensor(features(S, A))
        mu, sd = (v.double().numpy() for v in m.predict(X)); nz = m.noise_std(X).double().numpy()
        lat = np.sqrt(np.maximum(sd**2 - nz**2, 0))
        rows.append(dict(problem=k, goal=probs[k].goal, reached=bool(r.goal_reached), stuck=bool(r.stuck), final=float(r.states[-1, 4]),
                         spill=float(r.final_spill), steps=[dict(a=A[t].tolist(), s=S[t].tolist(), label=float(lab[t]), mu=float(mu[t]),
                         sd=float(sd[t]), lat=float(lat[t])) for t in range(len(A))]))
    json.dump(rows, open(out, "w"), indent=1)
    for r in rows:
        pp = all(st["mu"] + 2 * st["sd"] < .07 for st in r["steps"]); pl = all(st["mu"] + 2 * st["lat"] < .07 for st in r["steps"])
        desc = " ".join(f"{'M' if st['a'][0] < .5 else 'P'}({st['a'][1]:.2f},{st['a'][2]:.2f}) y{st['label']:.3f} mu{st['mu']:.3f} sd{st['sd']:.3f} lat{st['lat']:.3f}" for st in r["steps"])
        print(f"{r['problem']:2d} reached={int(r['reached'])} stuck={int(r['stuck'])} adm_pred={int(pp)} adm_lat={int(pl)} | {desc}")
