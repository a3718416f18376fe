# Scratch probe of session 27 (not part of the package; inputs: session 26 ceiling sets under /work/runs/s26_ceil06 and
# the 200-trajectory run under /work/runs/s26_200traj: edit the paths). Run from the repo root with PYTHONPATH=.
"""Scratch: the most-likely loop's mean GP started cold (BoTorch's default init) instead of warm from the
homoscedastic fit; refit on session 26's runs at round 20 and scored on the ceiling sets."""
import inspect, sys, textwrap, json
import mde.model as mm
src = textwrap.dedent(inspect.getsource(mm.HeteroscedasticGPMDE._most_likely_loop))
mode = sys.argv[1]
if mode == "cold":
    src = src.replace("            mean_gp.covar_module.load_state_dict(current.covar_module.state_dict())\n",
                      "            if it > 1:\n                mean_gp.covar_module.load_state_dict(current.covar_module.state_dict())\n")
    assert "if it > 1" in src
ns = dict(vars(mm))
exec(src, ns)
mm.HeteroscedasticGPMDE._most_likely_loop = ns["_most_likely_loop"]
from benchmarks.admission import run, format_table
from pathlib import Path
sets = [Path(f"/work/runs/s26_ceil06/ceiling_train_seed{k}.npz") for k in (0, 1, 2)]
r = run([Path("/work/runs/s26_200traj")], sets, ["world.problems.goal=[0.3,0.6]"], refit=[10, 20])
print(format_table(r))
json.dump(r, open(f"/work/runs/s27/cold/{mode}.json", "w"), default=str, indent=1)
