"""Session 42: each method's area under the test-success curve in one folder of runs minus the same seed's in another,
and the same for the model alone (each seed's ``model_only.csv``: its test problems' success rate).

    PYTHONPATH=. python benchmarks/scratch_s42/paired_lift.py BASE_DIR NEW_DIR OLD=NEW [OLD=NEW ...]

Per pair and for the model alone: both means, the mean paired difference over the seeds both folders hold, its 95 %
Student-t half-width and two-sided p; last, the mean over the pairs per seed (as ``benchmarks/scratch_s39/mean_lift.py``).
Session 42: ``results/quick_lognormal/csv results/quick_centred/csv random_plan_lognormal=random_plan
active_admission_lognormal=active_admission active_balanced_lognormal=active_balanced`` (the planner's aim).
"""

import csv
import sys
from pathlib import Path

import numpy as np
from scipy import stats

from active.baseline import rates
from active.report import mean_ci


def auc(path: Path) -> float:
    """Mean test success over the rounds of one run (``active.report``'s area)."""
    return float(np.mean([float(r["test_success"]) for r in csv.DictReader(open(path))]))


def model_alone(path: Path) -> float:
    """Share of the seed's test problems the model alone's plans solve (``active.baseline.rates``)."""
    return rates(list(csv.DictReader(open(path))))[0]


def line(name: str, old: np.ndarray, new: np.ndarray) -> np.ndarray:
    d = new - old
    _, half = mean_ci(d)
    print(f"{name:28s} {len(d):3d} seeds  base {old.mean():.3f}  new {new.mean():.3f}  diff {d.mean():+.3f} ± {half:.3f}"
          f"  (p = {stats.ttest_1samp(d, 0).pvalue:.3f}; {int((d > 0).sum())} up, {int((d < 0).sum())} down)")
    return d


base, new, pairs = Path(sys.argv[1]), Path(sys.argv[2]), [a.split("=", 1) for a in sys.argv[3:]]
seeds = sorted((s.name for s in new.glob("seed*") if all((new / s.name / n / "results.csv").exists()
                                                          and (base / s.name / o / "results.csv").exists() for o, n in pairs)),
               key=lambda s: int(s[4:]))
diffs = [line(n, np.array([auc(base / s / o / "results.csv") for s in seeds]),
              np.array([auc(new / s / n / "results.csv") for s in seeds])) for o, n in pairs]
line("the model alone", np.array([model_alone(base / s / "model_only.csv") for s in seeds]),
     np.array([model_alone(new / s / "model_only.csv") for s in seeds]))
mean = np.mean(diffs, axis=0)
_, half = mean_ci(mean)
print(f"mean over the {len(pairs)} methods: {mean.mean():+.3f} ± {half:.3f} (p = {stats.ttest_1samp(mean, 0).pvalue:.3f}); "
      f"{int((mean > 0).sum())} of {len(mean)} seeds up")
