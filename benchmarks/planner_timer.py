"""Times planner batches in a process of its own, on whichever source tree ``PYTHONPATH`` names first.

Why: :mod:`benchmarks.planner_profile` compares today's planner with a reference commit in one run (this
machine's speed drifts 2-3x between hours), so both must be timed alternately, each in a process that
imports its own tree. Run as a script (``python -P benchmarks/planner_timer.py ARGS_JSON``) from the
repository root (the dynamics cache is relative to it); it builds the batches with that tree's
:func:`benchmarks.planner_pool.experiment_batches`, prints ``ready``, then answers one JSON line per batch
name read from stdin: seconds, propagations and a digest of the plans (SHA-256 of their fingerprints).
"""

from __future__ import annotations

import hashlib
import json
import pickle
import sys
import time
from typing import Any


def _propagations(results: list) -> int:
    from planner.results import CandidateSet

    runs = [x for r in results for x in (r.runs if isinstance(r, CandidateSet) else [r])]
    return sum(int(x.stats.propagations) for x in runs)


def serve(args: dict[str, Any]) -> None:
    """Build the batches of ``args`` (overrides, mde, seed, iteration), then time the batches stdin names."""
    from active.run import compose_config
    from benchmarks.planner_pool import experiment_batches, fingerprint
    from mde.grouped import GroupedMDE
    from planner.pool import PlanPool

    cfg = compose_config(["experiment=quick", *args["overrides"]])
    dyn, planner_cfg, batches, _info = experiment_batches(cfg, args["seed"], args["iteration"])
    mde = GroupedMDE.load(args["mde"]) if args["mde"] else None
    pool = PlanPool(dyn, planner_cfg, workers=1)
    pool.run(batches["test"][:1], mde)  # lazy torch / OMPL set-up
    print("ready", flush=True)
    for line in sys.stdin:
        name = line.strip()
        t = time.perf_counter()
        got = pool.run(batches[name], mde)
        seconds = time.perf_counter() - t
        digest = hashlib.sha256(pickle.dumps([fingerprint(r) for r in got])).hexdigest()
        print(json.dumps({"seconds": seconds, "propagations": _propagations(got), "plans": digest}), flush=True)


if __name__ == "__main__":
    serve(json.loads(sys.argv[1]))
