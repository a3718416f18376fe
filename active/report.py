"""Aggregate any set of runs (one run, a seed sweep, several methods) into the paper's figures.

    python -m active.report outputs/quick multirun/2026-11-22/... --out report/

Finds every ``results.csv`` (and ``categories.csv``, ``calibration.csv`` beside it) below the given
directories and writes:

* ``learning_curves.png``: test success and plan-found rate per iteration and method, mean over
  seeds with a 95% confidence interval (Student t over seeds; the paper's Fig. 5);
* ``trajectory_types.png``: stacked ratios of training trajectory types per method (Fig. 4);
* ``calibration.png``: MDE interval coverage and NLL on held-out target-world transitions per iteration;
* ``summary.csv`` / ``summary.md``: area under the learning curve per method with its 95% CI.
"""

from __future__ import annotations

import argparse
import math
from collections import defaultdict
from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

import safeio  # noqa: E402
from .io import read_csv, write_csv  # noqa: E402

CATEGORY_ORDER = ("successful_pour", "unsuccessful_pour", "stuck_in_plant", "other")
CATEGORY_COLOURS = {"successful_pour": "#2c7fb8", "unsuccessful_pour": "#f03b20", "stuck_in_plant": "#31a354",
                    "other": "#bdbdbd"}


def mean_ci(values: Sequence[float], level: float = 0.95) -> tuple[float, float]:
    """Mean and half-width of the Student-t confidence interval (0 half-width for one value)."""
    v = np.asarray([x for x in values if not math.isnan(x)], float)
    if len(v) == 0:
        return float("nan"), float("nan")
    if len(v) == 1:
        return float(v[0]), 0.0
    half = stats.t.ppf(0.5 + level / 2, len(v) - 1) * v.std(ddof=1) / math.sqrt(len(v))
    return float(v.mean()), float(half)


def collect(dirs: Sequence[Path], name: str) -> list[dict[str, str]]:
    rows, seen = [], set()
    for d in dirs:
        d = Path(d)
        files = [d] if d.is_file() else sorted(d.rglob(name))
        for f in files:
            if f.name == name and f.resolve() not in seen:
                seen.add(f.resolve())
                rows.extend(read_csv(f))
    return rows


def _curves(rows: list[dict], key: str) -> dict[str, dict[int, list[float]]]:
    """method -> iteration -> values over seeds (last value per (method, seed, iteration))."""
    latest: dict[tuple, float] = {}
    for r in rows:
        latest[(r["method"], r["seed"], int(r["iteration"]))] = float(r[key])
    out: dict[str, dict[int, list[float]]] = defaultdict(lambda: defaultdict(list))
    for (m, _s, it), v in sorted(latest.items()):
        out[m][it].append(v)
    return out


def plot_learning_curves(rows: list[dict], path: Path) -> None:
    panels = [("test_success", "test success rate"), ("test_plan_found", "test plan found rate"),
              ("train_goal_reached", "training trajectories reaching the goal")]
    panels = [(k, t) for k, t in panels if all(k in r for r in rows)]
    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 3.8), dpi=110, sharey=True)
    for ax, (key, title) in zip(axes, panels):
        for m, curve in sorted(_curves(rows, key).items()):
            its = sorted(curve)
            mc = [mean_ci(curve[i]) for i in its]
            mean = np.array([a for a, _ in mc])
            half = np.array([b for _, b in mc])
            ax.plot(its, mean, marker="o", ms=3, label=m)
            ax.fill_between(its, np.clip(mean - half, 0, 1), np.clip(mean + half, 0, 1), alpha=0.2)
        ax.set_xlabel("iteration")
        ax.set_title(title)
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("rate (mean, 95% CI over seeds)")
    axes[-1].legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    safeio.save_figure(fig, path)
    plt.close(fig)


def plot_trajectory_types(rows: list[dict], path: Path) -> dict[str, dict[str, float]]:
    counts: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    for r in rows:
        counts[r["method"]][r["category"]] += 1
    methods = sorted(counts)
    ratios = {m: {c: counts[m][c] / max(1, sum(counts[m].values())) for c in CATEGORY_ORDER} for m in methods}
    fig, ax = plt.subplots(figsize=(1.6 + 1.2 * max(1, len(methods)), 3.8), dpi=110)
    bottom = np.zeros(len(methods))
    for c in CATEGORY_ORDER:
        vals = np.array([ratios[m][c] for m in methods])
        ax.bar(methods, vals, bottom=bottom, color=CATEGORY_COLOURS[c], label=c.replace("_", " "))
        bottom += vals
    ax.set_ylabel("ratio of training trajectories")
    ax.set_ylim(0, 1)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1, 1))
    plt.setp(ax.get_xticklabels(), rotation=20, ha="right", fontsize=8)
    fig.tight_layout()
    safeio.save_figure(fig, path)
    plt.close(fig)
    return ratios


def plot_calibration(rows: list[dict], path: Path) -> None:
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), dpi=110)
    for m, curve in sorted(_curves(rows, "coverage95").items()):
        its = sorted(curve)
        axes[0].plot(its, [np.mean(curve[i]) for i in its], marker="o", ms=3, label=m)
    axes[0].axhline(0.95, color="k", ls="--", lw=0.8)
    axes[0].set_title("95% interval coverage (held-out target transitions)")
    for m, curve in sorted(_curves(rows, "nll").items()):
        its = sorted(curve)
        axes[1].plot(its, [np.mean(curve[i]) for i in its], marker="o", ms=3, label=m)
    axes[1].set_title("mean negative log likelihood")
    for ax in axes:
        ax.set_xlabel("iteration")
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    safeio.save_figure(fig, path)
    plt.close(fig)


def summarise(rows: list[dict]) -> list[dict]:
    """Area under the learning curves (mean over iterations) per method, 95% CI over seeds.

    Besides test success and plan found, the mean share of training trajectories that reached their
    goal: what the method's choices did while collecting data (the paper's Fig. 4 in one number).
    """
    per: dict[str, dict[str, dict[int, tuple]]] = defaultdict(lambda: defaultdict(dict))
    for r in rows:
        per[r["method"]][r["seed"]][int(r["iteration"])] = (float(r["test_success"]), float(r["test_plan_found"]),
                                                            float(r.get("train_goal_reached") or "nan"))
    out = []
    for m in sorted(per):
        auc_s = [np.mean([v[0] for v in its.values()]) for its in per[m].values()]
        auc_p = [np.mean([v[1] for v in its.values()]) for its in per[m].values()]
        train = [np.mean([v[2] for v in its.values()]) for its in per[m].values()]
        final = [its[max(its)][0] for its in per[m].values()]
        (a, ah), (p, ph), (f, fh), (t, th) = mean_ci(auc_s), mean_ci(auc_p), mean_ci(final), mean_ci(train)
        out.append({"method": m, "seeds": len(per[m]), "auc_success": a, "auc_success_ci95": ah,
                    "auc_plan_found": p, "auc_plan_found_ci95": ph, "final_success": f, "final_success_ci95": fh,
                    "train_goal_reached": t, "train_goal_reached_ci95": th})
    return out


def report(dirs: Sequence[Path], out: Path) -> dict:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    results = collect(dirs, "results.csv")
    if not results:
        raise FileNotFoundError(f"no results.csv under {[str(d) for d in dirs]}")
    plot_learning_curves(results, out / "learning_curves.png")
    summary = summarise(results)
    write_csv(out / "summary.csv", summary)
    lines = ["| method | seeds | AUC success (95% CI) | AUC plan found (95% CI) | final success (95% CI) "
             "| training goal reached (95% CI) |",
             "|---|---|---|---|---|---|"]
    for s in summary:
        lines.append(f"| {s['method']} | {s['seeds']} | {s['auc_success']:.3f} ± {s['auc_success_ci95']:.3f} | "
                     f"{s['auc_plan_found']:.3f} ± {s['auc_plan_found_ci95']:.3f} | "
                     f"{s['final_success']:.3f} ± {s['final_success_ci95']:.3f} | "
                     f"{s['train_goal_reached']:.3f} ± {s['train_goal_reached_ci95']:.3f} |")
    safeio.write_text(out / "summary.md", "\n".join(lines) + "\n")
    made = {"learning_curves": str(out / "learning_curves.png"), "summary": summary, "table": "\n".join(lines)}
    cats = collect(dirs, "categories.csv")
    if cats:
        made["trajectory_types"] = plot_trajectory_types(cats, out / "trajectory_types.png")
    cal = collect(dirs, "calibration.csv")
    if cal:
        plot_calibration(cal, out / "calibration.png")
    return made


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m active.report", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dirs", nargs="+", type=Path, help="run or sweep directories (searched recursively)")
    ap.add_argument("--out", type=Path, default=Path("report"))
    args = ap.parse_args(argv)
    made = report(args.dirs, args.out)
    print(made["table"])
    print(f"figures in {args.out}")


if __name__ == "__main__":
    main()
