"""Session 42: what became of a ladder's ceiling test problems, as counts over all its training sets, in
``active.report``'s outcome classes (goal reached / clean pour, wrong amount / spilled / stuck in plant / other / no
plan found).

    PYTHONPATH=. python benchmarks/scratch_s42/ceiling_outcomes.py LADDER.json [LADDER.json ...]

Session 42: ``benchmarks/results/ladder_s41_default.json benchmarks/results/ceiling_s42_centred.json
benchmarks/results/ceiling_s42_centred_margin.json`` (the planner's aim).
"""

import json
import sys
from collections import Counter

from active.report import OUTCOMES, test_outcome

for path in sys.argv[1:]:
    ceiling = json.load(open(path))["ceiling"]
    problems = [q for s in ceiling.get("per_seed", [ceiling]) for q in s["problems"]]
    counts = Counter(test_outcome(q) for q in problems)
    print(path, len(problems), "problems:", ", ".join(f"{o} {counts[o]}" for o in OUTCOMES))
