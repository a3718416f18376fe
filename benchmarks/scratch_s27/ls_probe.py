# Scratch probe of session 27 (not part of the package; inputs: session 26 ceiling sets under /work/runs/s26_ceil06 and
# the 200-trajectory run under /work/runs/s26_200traj: edit the paths). Run from the repo root with PYTHONPATH=.
import inspect, textwrap, sys, torch, numpy as np
import mde.model as mm
from active.io import load_torch
from hydra.utils import instantiate
from active.run import compose_config
init = float(sys.argv[1]) if len(sys.argv) > 1 else None
src = textwrap.dedent(inspect.getsource(mm.HeteroscedasticGPMDE._most_likely_loop))
if init is not None:
    src = src.replace("            mean_gp.covar_module.load_state_dict(current.covar_module.state_dict())\n",
      "            if it > 1:\n                mean_gp.covar_module.load_state_dict(current.covar_module.state_dict())\n"
      "            else:\n                k = mean_gp.covar_module.base_kernel if hasattr(mean_gp.covar_module, 'base_kernel') else mean_gp.covar_module\n"
      "                k.lengthscale = torch.full_like(k.lengthscale, INIT)\n")
    ns = dict(vars(mm)); ns["INIT"] = init; exec(src, ns)
    mm.HeteroscedasticGPMDE._most_likely_loop = ns["_most_likely_loop"]
cfg = compose_config(["world.problems.goal=[0.3,0.6]"])
d = load_torch("/work/runs/s26_200traj/seed0/active_balanced/dataset.pt")
X, y = d["X"].numpy(), d["y"].numpy()
p = X[:, 5] == 1
m = instantiate(dict(cfg["mde"]), _convert_="all")
m.fit(X, y)
c = m._children[1.0]; f = c._fitted
k = f.mean_model.covar_module; k = getattr(k, "base_kernel", k)
np.set_printoptions(linewidth=250, suppress=True); print("init", init, "mean ls", np.round(k.lengthscale.detach().numpy().ravel(), 3), "sel it", f.info.get("selected_iteration"), "logml", np.round(f.info.get("log_ml_history"), 3))
