"""Why a training round finds no candidate: the round's candidate searches replayed with the run's MDE.

``PYTHONPATH=. python benchmarks/scratch_s22/fallback_probe.py RUN_METHOD_DIR --seed S --iteration I``
replays iteration I's first refit chunk of training problems (``experiment.candidates`` candidates each,
the iteration's beta) with the MDE the run fitted before it (``mde_iter{I-1}.pt``) and with no MDE,
and prints each planner run's termination, the closest its tree came to the goal and how many
transitions the precondition rejected."""

import argparse
from collections import Counter

import mde as mde_pkg
from active.run import compose_config
from benchmarks.planner_pool import experiment_batches
from planner.pool import PlanPool
from planner.results import CandidateSet

ap = argparse.ArgumentParser()
ap.add_argument("run")
ap.add_argument("--seed", type=int, required=True)
ap.add_argument("--iteration", type=int, required=True)
ap.add_argument("--refit", nargs="*", default=None,
                help="also refit the MDE on the run's data of iterations < I with these mde.* overrides")
ap.add_argument("overrides", nargs="*")
a = ap.parse_args()
cfg = compose_config(["experiment=quick", *a.overrides])
dyn, pcfg, batches, info = experiment_batches(cfg, a.seed, a.iteration)
print(info)
fitted = mde_pkg.load(f"{a.run}/mde_iter{a.iteration - 1:03d}.pt")
pool = PlanPool(dyn, pcfg, workers=1)
mdes = [("run's MDE", fitted), ("no MDE", None)]
if a.refit is not None:
    import csv
    import torch
    from hydra.utils import instantiate
    rows = list(csv.DictReader(open(f"{a.run}/results.csv")))
    n = int(rows[a.iteration - 2]["n_transitions"])
    data = torch.load(f"{a.run}/dataset.pt")
    refit = instantiate(compose_config(["experiment=quick", *a.refit])["mde"]).fit(data["X"][:n], data["y"][:n])
    mdes.insert(1, (f"refit on {n} transitions with {a.refit}", refit))
for name, m in mdes:
    res = pool.run(batches["train"], m)
    terms = Counter()
    print(f"--- {name}")
    for k, r in enumerate(res):
        runs = r.runs if isinstance(r, CandidateSet) else [r]
        for x in runs:
            terms[x.stats.termination] += 1
        print(f"problem {k}: {len(r.candidates) if isinstance(r, CandidateSet) else int(r.found)} found; "
              + "; ".join(f"{x.stats.termination} best {x.stats.best_goal_distance:.3f} rejected "
                          f"{x.stats.rejected}/{x.stats.propagations} tree {x.stats.tree_size}" for x in runs))
    print(dict(terms))
