"""Session 39: the per-seed mean, over several methods, of one setting's AUC of test success minus another's.

    python benchmarks/scratch_s39/mean_lift.py BASE_DIR NEW_DIR OLD=NEW [OLD=NEW ...]

For each seed that both folders hold for every given pair (``seedN/METHOD/results.csv``), the mean over the pairs of
AUC(NEW_DIR/seedN/NEW) - AUC(BASE_DIR/seedN/OLD), the AUC being the mean test success over the rounds (as
``active.report``); then the mean over seeds, its 95 % Student-t half-width and the two-sided p of a one-sample t-test.
Session 39: ``results/quick/csv results/quick_lognormal/csv active_balanced=active_balanced_lognormal
random_plan=random_plan_lognormal active_admission=active_admission_lognormal`` (seeds 0-11: alpha has no others);
session 40: the last two pairs (seeds 0-23).
"""

import csv
import sys
from pathlib import Path

import numpy as np
from scipy import stats


def auc(path: Path) -> float:
    return float(np.mean([float(r["test_success"]) for r in csv.DictReader(open(path))]))


base, new, pairs = Path(sys.argv[1]), Path(sys.argv[2]), [a.split("=", 1) for a in sys.argv[3:]]
seeds = sorted((s.name for s in new.glob("seed*") if all((new / s.name / n / "results.csv").exists()
                                                          and (base / s.name / o / "results.csv").exists() for o, n in pairs)),
               key=lambda s: int(s[4:]))
lift = np.array([np.mean([auc(new / s / n / "results.csv") - auc(base / s / o / "results.csv") for o, n in pairs])
                 for s in seeds])
half = stats.t.ppf(0.975, len(lift) - 1) * lift.std(ddof=1) / np.sqrt(len(lift))
print(f"{len(seeds)} seeds, mean lift {lift.mean():+.3f} ± {half:.3f} (p = {stats.ttest_1samp(lift, 0).pvalue:.3f}); "
      f"{int((lift > 0).sum())} of {len(lift)} seeds up; per seed {np.round(lift, 3).tolist()}")
