"""Session 43: two methods' mean test success over a window of rounds, paired seed for seed within one folder of runs.

    PYTHONPATH=. python benchmarks/scratch_s43/window_diff.py CSV_DIR A B [--rounds FIRST LAST] [--seeds FIRST LAST] [--by-round]

CSV_DIR holds ``seed<k>/<method>/results.csv`` (``benchmarks/collect_csvs.py``). Prints both means, the mean of A - B
over the seeds that hold both, its 95 % Student-t half-width (``active.report.mean_ci``), two-sided p and the count of
seeds up and down. Rounds are 1-based and inclusive; all rounds give the report's area under the curve. Session 43:
``results/quick_centred/csv active_admission random_plan`` with ``--rounds 1 3 --seeds 12 23`` (the confirmation,
written down before those seeds ran) and without options (the 24-seed area). ``--by-round`` (session 44) also prints
each method's mean test success per round over the same seeds.
"""

import argparse
import csv
from pathlib import Path

import numpy as np
from scipy import stats

from active.report import mean_ci


def successes(path: Path) -> np.ndarray:
    """Test success per round of one run, in round order."""
    return np.array([float(r["test_success"]) for r in csv.DictReader(open(path))])


p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
p.add_argument("csv_dir", type=Path)
p.add_argument("a")
p.add_argument("b")
p.add_argument("--rounds", type=int, nargs=2, metavar=("FIRST", "LAST"))
p.add_argument("--seeds", type=int, nargs=2, metavar=("FIRST", "LAST"))
p.add_argument("--by-round", action="store_true", help="also the mean test success per round of each method")
args = p.parse_args()
seeds = sorted(int(d.name[4:]) for d in args.csv_dir.glob("seed*")
               if all((d / m / "results.csv").is_file() for m in (args.a, args.b)))
if args.seeds:
    seeds = [s for s in seeds if args.seeds[0] <= s <= args.seeds[1]]
if len(seeds) < 2:
    raise SystemExit(f"{args.csv_dir}: {len(seeds)} seed(s) hold both {args.a} and {args.b}; need at least 2")
lo, hi = (args.rounds[0] - 1, args.rounds[1]) if args.rounds else (0, None)
curves = {m: [successes(args.csv_dir / f"seed{s}" / m / "results.csv") for s in seeds] for m in (args.a, args.b)}
mean = {m: np.array([c[lo:hi].mean() for c in cs]) for m, cs in curves.items()}
d = mean[args.a] - mean[args.b]
_, half = mean_ci(d)
window = f"rounds {args.rounds[0]}-{args.rounds[1]}" if args.rounds else "all rounds"
print(f"{window}, seeds {seeds[0]}-{seeds[-1]} ({len(seeds)}): {args.a} {mean[args.a].mean():.3f}  {args.b} "
      f"{mean[args.b].mean():.3f}  difference {d.mean():+.3f} ± {half:.3f} (p = {stats.ttest_1samp(d, 0).pvalue:.3f}; "
      f"{int((d > 0).sum())} up, {int((d < 0).sum())} down)")
if args.by_round:
    for m, cs in curves.items():
        print(f"  {m} by round: " + " ".join(f"{x:.2f}" for x in np.mean(cs, 0)))
