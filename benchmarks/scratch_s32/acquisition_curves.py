"""Session 32: the quick experiment's learning curves under each acquisition, against random_plan, and what the
methods collected against where their test plans ended (one figure, two panels of curves and one scatter).

    python benchmarks/scratch_s32/acquisition_curves.py OUT.png RP_DIR:random_plan:random_plan \
        ALPHA_DIR:active_balanced:alpha LCB_DIR:active_balanced:lcb ...

Each argument is RUN_DIR:METHOD:LABEL (RUN_DIR holds seed*/METHOD/{results,categories,tests}.csv); the seeds
common to all runs are used. Means over seeds; the report's CIs are in the summary tables.
"""

import csv
import glob
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def rows(pattern: str) -> list[dict]:
    out = []
    for f in sorted(glob.glob(pattern)):
        out += list(csv.DictReader(open(f)))
    return out


def main(out: str, specs: list[str]) -> None:
    runs = [s.rsplit(":", 2) for s in specs]
    fig, axes = plt.subplots(1, 3, figsize=(14, 4), dpi=110)
    for d, m, label in runs:
        res = rows(f"{d}/seed*/{m}/results.csv")
        its = sorted({int(r["iteration"]) for r in res})
        for ax, key in zip(axes[:2], ("test_success", "test_plan_found")):
            ax.plot(its, [np.mean([float(r[key]) for r in res if int(r["iteration"]) == i]) for i in its],
                    marker="o", lw=2 if m == "random_plan" else 1.2, color="k" if m == "random_plan" else None,
                    label=label)
        cats = rows(f"{d}/seed*/{m}/categories.csv")
        tests = [r for r in rows(f"{d}/seed*/{m}/tests.csv")]
        train_stuck = np.mean([r["category"] == "stuck_in_plant" for r in cats])
        test_stuck = np.mean([r["found"] == "True" and r["category"] == "stuck_in_plant" for r in tests])
        axes[2].scatter(train_stuck, test_stuck, s=50, color="k" if m == "random_plan" else None)
        axes[2].annotate(label, (train_stuck, test_stuck), textcoords="offset points", xytext=(5, 4), fontsize=8)
    for ax, t in zip(axes[:2], ("test success", "plans found")):
        ax.set_xlabel("iteration (6 trajectories each)")
        ax.set_ylabel(t + " (mean over seeds)")
        ax.set_ylim(0, 1)
    axes[1].legend(fontsize=8)
    axes[2].set_xlabel("training trajectories stuck in the plant (share)")
    axes[2].set_ylabel("test problems whose plan ended in the plant (share)")
    axes[2].set_xlim(0, 0.45)
    axes[2].set_ylim(0, 0.1)
    fig.tight_layout()
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
