"""PYTHONPATH=. python benchmarks/scratch_s38/acquisition_cost.py MDE_CHECKPOINT DATASET_PT
Milliseconds per candidate of the paper's alpha and of the look-ahead (TrajectoryAdmissionGain) on a run's saved MDE:
30 six-step candidates cut from the run's own data, a reference of 150 jittered data rows (session 38's figure:
RUN/seed0/active_admission/mde_iter007.pt and dataset.pt of the quick experiment)."""
import sys, time, torch
import mde as M
from active.acquisition import DiscountedMaxUCB, TrajectoryAdmissionGain
m = M.load(sys.argv[1])
X = torch.load(sys.argv[2], weights_only=False)["X"]
g = torch.Generator().manual_seed(0)
ref = X[torch.randperm(len(X), generator=g)[:150]] + 0.001 * torch.randn(150, X.shape[1], generator=g, dtype=X.dtype)
ref[:, 5] = X[torch.randperm(len(X), generator=g)[:150], 5]  # the skill column stays a skill code
cands = [X[i:i + 6] for i in range(0, 180, 6)]
print("transitions", len(X))
for cls, kw in ((DiscountedMaxUCB, {"c": 0.1}), (TrajectoryAdmissionGain, {"reference": ref})):
    t = time.perf_counter()
    acq = cls(m.marginal_model, **kw)
    with torch.no_grad():
        [float(acq(c.unsqueeze(0))) for c in cands]
    print(f"{cls.__name__}: {(time.perf_counter() - t) / len(cands) * 1e3:.1f} ms per candidate")
