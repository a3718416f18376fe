"""Scratch (session 16): target-world trajectories aimed at the safe pour region under the plant (session 15's map:
(0.32, 0.14), theta 1.1-1.4), appended to a saved ceiling dataset, so that the ceiling rung can tell "the data never
covers the safe region" from "the MDE cannot represent it".
python benchmarks/scratch_s16/targeted_data.py BASE.npz K OUT.npz"""
import sys, warnings
import numpy as np
warnings.filterwarnings("ignore")
from active.loop import _stack_steps, derive_seed
from active.run import compose_config
from planner.sampling import ActionSampler
from active.loop import build_planner_config
from active.experiment import ExperimentConfig
from sim.execute import PouringExecutor
from sim.world import WorldConfig
from task.problems import sample_problems

base_path, K, out_path = sys.argv[1], int(sys.argv[2]), sys.argv[3]
cfg = compose_config(["progress=false"]); w = WorldConfig.from_mapping(cfg["world"])
exp = ExperimentConfig.from_mapping(cfg["experiment"])
sampler = ActionSampler(build_planner_config(w, cfg["planner"], exp))
rng = np.random.default_rng(derive_seed(16, "targeted-ceiling"))
probs = sample_problems(w, K, derive_seed(16, "targeted-ceiling-problems"), world="target")
acts = []
for _ in probs:
    x = 0.32 + 0.01 * rng.integers(-1, 3)          # 0.31-0.34 on the 1 cm lattice
    y = 0.14 + 0.01 * rng.integers(0, 3)           # 0.14-0.16
    seq = [[0, x, y], [1, rng.uniform(1.0, 1.5), rng.uniform(0.0, 1.0)]]
    seq += [list(r) for r in sampler.sample(2, rng)]
    acts.append(np.array(seq))
ex = PouringExecutor(w)
res = []
for i in range(0, K, 32):
    ch = probs[i:i + 32]
    res += ex.run("target", np.array([p.start[:3] for p in ch]), acts[i:i + 32],
                  plant_jitter=np.array([p.plant_jitter for p in ch]), goals=[p.goal for p in ch])
    print(f"{i + len(ch)}/{K}", flush=True)
s, a, s2 = _stack_steps(res)
kept = [(i, r) for i, r in enumerate(res) if not r.unstable]
traj = np.array([i for i, r in kept for _ in r.steps], dtype=int)
with np.load(base_path) as f:
    b = {k: f[k] for k in f.files}
n0 = len(b["category"])
out = {"s": np.r_[b["s"], s], "a": np.r_[b["a"], a], "s_next": np.r_[b["s_next"], s2],
       "trajectory": np.r_[b["trajectory"], n0 + traj], "category": np.r_[b["category"], [r.category for r in res]],
       "train_plans_found": b["train_plans_found"]}
np.savez(out_path, **out)
cats = {c: int(np.sum(np.array([r.category for r in res]) == c)) for c in set(r.category for r in res)}
print("targeted categories:", cats, "transitions", len(s))
