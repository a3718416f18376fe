"""Does the dynamics MLP ensemble's held-out pour error fall with more source data? (scratch)"""
import sys, warnings, time, json
import numpy as np
warnings.filterwarnings("ignore")
import dynamics
from dynamics.data import Transitions
from dynamics.config import DynamicsConfig, single_models
from dynamics.train import fit
from dynamics.ensemble import DynamicsEnsemble
from active.run import compose_config
cfg = compose_config(["progress=false"])
A = Transitions.load("/work/main/.cache/dynamics/data-cddfb0aa9e5a637a/dataset.pt")
B = Transitions.load("/work/main/.cache/dynamics/data-85e082618221f00b/dataset.pt")
# B's trajectories that are not copies of an A trajectory (shared random streams)
keyA = {tuple(np.round(np.r_[s, a], 6)) for s, a in zip(A.s, A.a)}
newrow = np.array([tuple(np.round(np.r_[s, a], 6)) not in keyA for s, a in zip(B.s, B.a)])
tr_new = np.unique(B.traj[newrow])
ut = tr_new.copy(); np.random.default_rng(0).shuffle(ut)
B1 = np.isin(B.traj, ut[: len(ut) // 2]); B2 = np.isin(B.traj, ut[len(ut) // 2:]) & newrow
test = B.subset(np.flatnonzero(B2))
off = A.traj.max() + 1
b1 = B.subset(np.flatnonzero(B1)); b1.traj = b1.traj + off
print("A", len(A), "B1", len(b1), "test", len(test), flush=True)
def score(model, name):
    s, a, s2 = test.s, test.a, test.s_next
    p = model.predict_np(s, a)
    P = (a[:, 0] == 1) & (s[:, 3] > 0.05) & (np.abs(s2[:, 2]) < 0.05)
    mv = P & (np.abs(s2[:, 4] - s[:, 4]) > 0.02)
    e = p[:, 4] - s2[:, 4]
    d = np.abs(p[:, :2] - s2[:, :2]).sum(1) * 0  # not used
    res = {"moved_pours": int(mv.sum()), "abs_err_vtgt_moved": float(np.abs(e[mv]).mean()), "bias_moved": float(e[mv].mean()),
           "abs_err_vctrl_moved": float(np.abs(p[mv, 3] - s2[mv, 3]).mean()),
           "later_moved_abs_err": float(np.abs(e[mv & (s[:, 3] < 0.97)]).mean())}
    print(name, json.dumps(res), flush=True); return res
dc = DynamicsConfig.from_dict(cfg["dynamics"]) if hasattr(DynamicsConfig, "from_dict") else None
base = dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False)
out = {"default (A, 48 batches)": score(base, "default")}
both = Transitions.concat([A, b1], meta=dict(A.meta))
t0 = time.time()
members = [fit(both, m.model, m.train, world_cfg=cfg["world"]) for m in single_models(dc)]
print("trained", time.time() - t0, flush=True)
out["A + B1 (~72 batches)"] = score(DynamicsEnsemble(members), "A+B1")
json.dump(out, open("/tmp/scratch/more_data.json", "w"), indent=1)
