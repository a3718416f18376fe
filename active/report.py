"""Aggregate any set of runs (one run, a seed sweep, several methods) into the paper's figures.

    python -m active.report outputs/quick multirun/2026-11-22/... --out report/

Finds every ``results.csv`` (and ``categories.csv``, ``calibration.csv`` beside it) below the given
directories and writes:

* ``learning_curves.png``: test success and plan-found rate per iteration and method, mean over
  seeds with a 95% confidence interval (Student t over seeds; the paper's Fig. 5);
* ``trajectory_types.png``: stacked ratios of training trajectory types per method (Fig. 4), also in
  ``trajectory_types.csv`` (per iteration) and a table in ``summary.md``;
* ``test_outcomes.png`` (where the runs wrote ``tests.csv``): what became of the test problems, per method
  and iteration (goal reached, no plan found, or the executed plan's failure: stuck in the plant, spilled,
  a clean pour of the wrong amount, other), beside the model alone's; shares also in ``test_outcomes.csv``
  and a table in ``summary.md``;
* ``calibration.png``: MDE interval coverage and NLL on held-out target-world transitions per iteration;
* ``summary.csv`` / ``summary.md``: area under the learning curve per method with its 95% CI;
* ``paired.csv`` (and a second table in ``summary.md``): per method, the difference of its AUC to a
  reference method's (``--reference``, default ``random_plan`` when present, otherwise every pair),
  paired over the seeds both have, since a seed fixes the train and test problems for every method;
  ``paired_seeds.csv`` holds the per-seed differences;
* where the runs wrote ``model_only.csv`` (:mod:`active.baseline`: the model alone, no MDE, on each seed's
  test problems): its success and plan-found rates as dotted lines, and ``paired_model_only.csv`` (a third
  table in ``summary.md``): each method's AUC minus the model alone's rate, paired over seeds;
* with ``--ceiling outputs/ladder/ladder.json``: the ceiling of ``python -m active.ladder`` (an MDE
  fitted on a large target-world dataset, the best any data collection can hope for) as a dashed line
  on the test-success and plan-found panels and as a line under the summary table.
"""

from __future__ import annotations

import argparse
import json
import math
import zlib
from collections import Counter, defaultdict
from itertools import combinations
from pathlib import Path
from typing import Any, Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402
from scipy import stats  # noqa: E402

import safeio  # noqa: E402

from .baseline import FILE as MODEL_ONLY_FILE  # noqa: E402
from .baseline import is_true, latest_rows  # noqa: E402
from .baseline import rates as model_only_rates  # noqa: E402
from .identity import comparable_config, flatten  # noqa: E402
from .io import RunFileError, read_csv, write_csv  # noqa: E402
from .oracle import BOUND_NAMES  # noqa: E402

CATEGORY_ORDER = ("successful_pour", "unsuccessful_pour", "stuck_in_plant", "other")
CATEGORY_COLOURS = {
    "successful_pour": "#2c7fb8",
    "unsuccessful_pour": "#f03b20",
    "stuck_in_plant": "#31a354",
    "other": "#bdbdbd",
}
DEFAULT_REFERENCE = "random_plan"
CEILING_PANELS = {"test_success": "success", "test_plan_found": "found"}  # panel -> key of the ceiling entry
MODEL_ONLY = "model alone (no MDE)"  # the reference name of the model-only rows in paired tables
#: what became of a test problem (:func:`test_outcome`), in stacking order, with its colour
OUTCOMES = {
    "goal_reached": "#2c7fb8",
    "clean_pour_wrong_amount": "#a6bddb",
    "spilled": "#f03b20",
    "stuck_in_plant": "#31a354",
    "other": "#bdbdbd",
    "no_plan_found": "#fed976",
}
#: test-outcome column: the share of found plans that reached the goal (how good the admitted plans are, apart
#: from how many the precondition admits: "no plan found")
GIVEN_PLAN = "goal_reached_given_plan"
OUTCOME_OF_CATEGORY = {
    "successful_pour": "clean_pour_wrong_amount",
    "unsuccessful_pour": "spilled",
    "stuck_in_plant": "stuck_in_plant",
    "other": "other",
}
#: one colour per method in every figure, whatever methods a report holds (colour-blind-safe, Okabe-Ito first);
#: a method not listed gets one of FALLBACK_COLOURS by a stable hash of its name
METHOD_COLOURS = {
    "random_plan": "#0072B2",
    "active_balanced": "#D55E00",
    "active_admission": "#009E73",
    "model_plan": "#CC79A7",
    "random_actions": "#E69F00",
    "active_cautious": "#56B4E9",
    "active_mean": "#F0E442",
    "active_straddle": "#882255",
    "active_thompson": "#44AA99",
    "oracle": "#000000",
}
FALLBACK_COLOURS = ("#332288", "#117733", "#999933", "#AA4499", "#661100", "#6699CC", "#888888")


def method_colour(method: str) -> str:
    """The colour of ``method`` in every figure (the same in every report)."""
    if method in METHOD_COLOURS:
        return METHOD_COLOURS[method]
    return FALLBACK_COLOURS[zlib.crc32(method.encode()) % len(FALLBACK_COLOURS)]


def label(key: str) -> str:
    """A column name as figure and table text."""
    return key.replace("_", " ")


def save_figure(fig: Any, path: Path) -> None:
    """The figure as PNG (to look at) and PDF (to print or put in a paper), both atomically."""
    safeio.save_figure(fig, path)
    safeio.save_figure(fig, path.with_suffix(".pdf"))


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
        if r.get(key) not in (None, ""):  # e.g. a calibration row from before the column existed
            latest[(r["method"], r["seed"], int(r["iteration"]))] = float(r[key])
    out: dict[str, dict[int, list[float]]] = defaultdict(lambda: defaultdict(list))
    for (m, _s, it), v in sorted(latest.items()):
        out[m][it].append(v)
    return out


def _trajectories_at(rows: list[dict]) -> dict[tuple[str, int], float]:
    """(method, iteration) -> the training trajectories executed by then (mean over seeds; empty when the rows do
    not say), the learning curves' x-axis: data, the cost active learning is about, not rounds."""
    per: dict[tuple[str, int], list[float]] = defaultdict(list)
    for r in rows:
        if r.get("n_trajectories") not in (None, ""):
            per[(r["method"], int(r["iteration"]))].append(float(r["n_trajectories"]))
    return {k: float(np.mean(v)) for k, v in per.items()}


def plot_learning_curves(
    rows: list[dict],
    path: Path,
    ceiling: Mapping[str, Any] | None = None,
    model_only: Mapping[str, tuple[float, float]] | None = None,
) -> dict[str, tuple[float, str]]:
    """Fig. 5; with ``ceiling`` (see :func:`load_ceiling`) a dashed line at the ceiling's success and
    plan-found rate, so a reader sees how far each method is from what the MDE can reach at all; with
    ``model_only`` (panel -> (mean, CI half-width) over seeds, :func:`model_only_summary`) a dotted line
    at the model alone's rates on the same test problems: below it, the precondition costs more good
    plans than it saves.

    Returns panel -> (y, label) of the ceiling lines as drawn (read back from the axes)."""
    panels = [
        ("test_success", "test success rate"),
        ("test_plan_found", "test plan found rate"),
        ("train_goal_reached", "training trajectories reaching the goal"),
    ]
    panels = [(k, t) for k, t in panels if all(k in r for r in rows)]
    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 3.8), dpi=110, sharey=True, squeeze=False)
    axes = axes[0]
    drawn: dict[str, tuple[float, str]] = {}
    # methods run on different seed sets (a sweep extended for some methods only) are told apart in the legend
    n_seeds = Counter(m for m, _s in {(r["method"], r["seed"]) for r in rows})
    trajectories = _trajectories_at(rows)
    for ax, (key, title) in zip(axes, panels):
        for m, curve in sorted(_curves(rows, key).items()):
            its = sorted(curve)
            xs = [trajectories.get((m, i), i) for i in its]
            mc = [mean_ci(curve[i]) for i in its]
            mean = np.array([a for a, _ in mc])
            half = np.array([b for _, b in mc])
            colour, seeds = method_colour(m), f"{n_seeds[m]} seed{'' if n_seeds[m] == 1 else 's'}"
            ax.plot(
                xs,
                mean,
                marker="o",
                ms=3,
                color=colour,
                ls="--" if m in BOUND_NAMES else "-",  # a bound (active.oracle), not a method
                label=f"{m}{' (bound)' if m in BOUND_NAMES else ''} ({seeds})",
            )
            ax.fill_between(xs, np.clip(mean - half, 0, 1), np.clip(mean + half, 0, 1), color=colour, alpha=0.2)
        if ceiling is not None and key in CEILING_PANELS:
            line = ax.axhline(
                float(ceiling[CEILING_PANELS[key]]), color="k", ls="--", lw=1.0, label=ceiling_label(ceiling)
            )
            drawn[key] = (float(line.get_ydata()[0]), str(line.get_label()))
        if model_only and key in model_only:
            mean, half = model_only[key]
            line = ax.axhline(mean, color="0.35", ls=":", lw=1.5, label=f"{MODEL_ONLY} ± 95% CI")
            ax.axhspan(max(mean - half, 0.0), min(mean + half, 1.0), color="0.5", alpha=0.08)
            drawn[f"model_only:{key}"] = (float(line.get_ydata()[0]), str(line.get_label()))
        ax.set_xlabel("training trajectories executed" if trajectories else "iteration")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # whole trajectories / iterations
        ax.set_title(title)
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("rate (mean, 95% CI over seeds)")
    # the first panel (test success) has every method and the ceiling: one legend for all panels
    # beside the last panel, since a ceiling line often runs through the upper left corner
    beside = ceiling is not None or bool(model_only)
    legend_at = {"loc": "upper left", "bbox_to_anchor": (1.02, 1)} if beside else {"loc": "upper left"}
    axes[-1].legend(*axes[0].get_legend_handles_labels(), fontsize=8, **legend_at)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return drawn


def trajectory_type_table(rows: Sequence[Mapping[str, Any]]) -> list[dict]:
    """Rows of ``trajectory_types.csv``: per method and iteration (and ``all``), the share of each training
    trajectory type (:data:`CATEGORY_ORDER`; a category outside it counts as ``other``) over its seeds."""
    groups: dict[tuple[str, str], list[str]] = defaultdict(list)
    for r in rows:
        c = r["category"] if r["category"] in CATEGORY_ORDER else "other"
        groups[(r["method"], str(r["iteration"]))].append(c)
        groups[(r["method"], "all")].append(c)
    order = sorted(groups, key=lambda k: (k[0], k[1] == "all", int(k[1]) if k[1] != "all" else 0))
    return [
        {
            "method": m,
            "iteration": it,
            "n": len(groups[(m, it)]),
            **{c: round(groups[(m, it)].count(c) / len(groups[(m, it)]), 4) for c in CATEGORY_ORDER},
        }
        for m, it in order
    ]


def trajectory_type_lines(table: list[dict]) -> list[str]:
    """The ``all`` rows of :func:`trajectory_type_table` as a markdown table for ``summary.md``: what the
    methods collected (the paper's Fig. 4a), to read beside what became of the test problems."""
    lines = [
        "Training trajectories by type (share over all iterations and seeds; the paper's Fig. 4a):",
        "",
        "| method | trajectories | " + " | ".join(c.replace("_", " ") for c in CATEGORY_ORDER) + " |",
        "|---|---:|" + "---:|" * len(CATEGORY_ORDER),
    ]
    for r in table:
        if r["iteration"] == "all":
            lines.append(
                f"| {r['method']} | {r['n']} | " + " | ".join(f"{float(r[c]):.2f}" for c in CATEGORY_ORDER) + " |"
            )
    return lines


def plot_trajectory_types(table: list[dict], path: Path) -> dict[str, dict[str, float]]:
    """Stacked shares of the training trajectory types per method (the ``all`` rows of
    :func:`trajectory_type_table`); returns them as {method: {category: share}}."""
    ratios = {r["method"]: {c: float(r[c]) for c in CATEGORY_ORDER} for r in table if r["iteration"] == "all"}
    methods = sorted(ratios)
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
    save_figure(fig, path)
    plt.close(fig)
    return ratios


def test_outcome(row: Mapping[str, Any]) -> str:
    """One test problem's outcome (a key of :data:`OUTCOMES`) from its ``tests.csv`` / ``model_only.csv`` row."""
    if not is_true(row["found"]):
        return "no_plan_found"
    if is_true(row["goal_reached"]):
        return "goal_reached"
    return OUTCOME_OF_CATEGORY.get(str(row["category"]), "other")


def outcome_shares(rows: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """Share of each outcome among ``rows`` (all of :data:`OUTCOMES`, zeros included)."""
    n = max(1, len(rows))
    counts = defaultdict(int)
    for r in rows:
        counts[test_outcome(r)] += 1
    return {o: counts[o] / n for o in OUTCOMES}


def test_outcome_table(tests: list[dict], alone: list[dict]) -> list[dict]:
    """Rows of ``test_outcomes.csv``: per method and iteration (and ``all``), the share of each outcome over
    its seeds' test problems, and :data:`GIVEN_PLAN` (empty where no plan was found); the model alone's (one set
    of problems per seed) as ``iteration = all``. A
    (method, seed, iteration, problem) found in several files counts once (the last row)."""
    latest = {(r["method"], str(r["seed"]), int(r["iteration"]), r["problem"]): r for r in tests}
    groups: dict[tuple[str, str], list] = defaultdict(list)
    for (m, _s, it, _p), r in latest.items():
        groups[(m, str(it))].append(r)
        groups[(m, "all")].append(r)
    if alone:
        groups[(MODEL_ONLY, "all")] = latest_rows(alone)
    order = sorted(groups, key=lambda k: (k[0] == MODEL_ONLY, k[0], k[1] == "all", int(k[1]) if k[1] != "all" else 0))
    table = []
    for m, it in order:
        shares = outcome_shares(groups[(m, it)])
        found = 1.0 - shares["no_plan_found"]
        table.append(
            {
                "method": m,
                "iteration": it,
                "n": len(groups[(m, it)]),
                **{o: round(v, 4) for o, v in shares.items()},
                GIVEN_PLAN: round(shares["goal_reached"] / found, 4) if found > 0 else "",
            }
        )
    return table


def plot_test_outcomes(table: list[dict], path: Path) -> None:
    """One panel per method: stacked outcome shares of the test problems by iteration, and the model alone's
    (the same problems, no MDE) as a bar of its own at the right, so where a method loses plans shows."""
    methods = sorted({r["method"] for r in table if r["method"] != MODEL_ONLY})
    alone = [r for r in table if r["method"] == MODEL_ONLY]
    fig, axes = plt.subplots(
        1, max(1, len(methods)), figsize=(1.5 + 3.6 * max(1, len(methods)), 3.8), dpi=110, sharey=True, squeeze=False
    )
    for ax, m in zip(axes[0], methods):
        rows = [r for r in table if r["method"] == m and r["iteration"] != "all"]
        labels = [str(r["iteration"]) for r in rows] + (["alone"] if alone else [])
        rows = rows + alone[:1]
        bottom = np.zeros(len(rows))
        for o, colour in OUTCOMES.items():
            vals = np.array([float(r[o]) for r in rows])
            ax.bar(range(len(rows)), vals, bottom=bottom, color=colour, label=label(o), width=0.8)
            bottom += vals
        ax.set_xticks(range(len(rows)), labels, fontsize=8)
        ax.set_title(m, fontsize=10)
        ax.set_xlabel("iteration" + (" (and the model alone)" if alone else ""))
        ax.set_ylim(0, 1)
    axes[0][0].set_ylabel("share of test problems (all seeds)")
    axes[0][-1].legend(*axes[0][0].get_legend_handles_labels(), fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1))
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def test_outcome_lines(table: list[dict]) -> list[str]:
    """The ``all`` rows of :func:`test_outcome_table` as a markdown table for ``summary.md``."""
    lines = [
        "What became of the test problems (share over all iterations and seeds; the last column is the share of "
        "found plans that reached the goal, which separates how good the admitted plans are from how many "
        "the precondition admits):",
        "",
        "| method | problems | " + " | ".join(map(label, OUTCOMES)) + f" | {label(GIVEN_PLAN)} |",
        "|---|---:|" + "---:|" * (len(OUTCOMES) + 1),
    ]
    for r in table:
        if r["iteration"] == "all":
            given = f"{float(r[GIVEN_PLAN]):.2f}" if r[GIVEN_PLAN] != "" else "-"
            lines.append(
                f"| {r['method']} | {r['n']} | " + " | ".join(f"{float(r[o]):.2f}" for o in OUTCOMES) + f" | {given} |"
            )
    return lines


def plot_calibration(rows: list[dict], path: Path) -> None:
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), dpi=110)
    for m, curve in sorted(_curves(rows, "coverage95").items()):
        its = sorted(curve)
        axes[0].plot(its, [np.mean(curve[i]) for i in its], marker="o", ms=3, color=method_colour(m), label=m)
    axes[0].axhline(0.95, color="k", ls="--", lw=0.8)
    axes[0].set_title(
        "95% interval coverage (held-out target transitions,\nlabels as fitted: capped at label_max)", fontsize=9
    )
    for m, curve in sorted(_curves(rows, "nll").items()):
        its = sorted(curve)
        axes[1].plot(its, [np.mean(curve[i]) for i in its], marker="o", ms=3, color=method_colour(m), label=m)
    axes[1].set_yscale("symlog", linthresh=1.0)  # an early fit's NLL can be 1e8 beside later ones near 0
    axes[1].set_title("mean negative log likelihood (symlog)")
    for ax in axes:
        ax.set_xlabel("iteration")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # iterations are whole numbers
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def _per_seed(rows: list[dict]) -> dict[str, dict[str, dict[int, tuple]]]:
    """method -> seed -> iteration -> (test success, plan found, training goal reached); last row wins."""
    per: dict[str, dict[str, dict[int, tuple]]] = defaultdict(lambda: defaultdict(dict))
    for r in rows:
        per[r["method"]][r["seed"]][int(r["iteration"])] = (
            float(r["test_success"]),
            float(r["test_plan_found"]),
            float(r.get("train_goal_reached") or "nan"),
        )
    return per


def summarise(rows: list[dict]) -> list[dict]:
    """Area under the learning curves (mean over iterations) per method, 95% CI over seeds.

    Besides test success and plan found, the mean share of training trajectories that reached their
    goal: what the method's choices did while collecting data (the paper's Fig. 4 in one number).
    """
    per = _per_seed(rows)
    out = []
    for m in sorted(per):
        auc_s = [np.mean([v[0] for v in its.values()]) for its in per[m].values()]
        auc_p = [np.mean([v[1] for v in its.values()]) for its in per[m].values()]
        train = [np.mean([v[2] for v in its.values()]) for its in per[m].values()]
        final = [its[max(its)][0] for its in per[m].values()]
        (a, ah), (p, ph), (f, fh), (t, th) = mean_ci(auc_s), mean_ci(auc_p), mean_ci(final), mean_ci(train)
        out.append(
            {
                "method": m,
                "seeds": len(per[m]),
                "auc_success": a,
                "auc_success_ci95": ah,
                "auc_plan_found": p,
                "auc_plan_found_ci95": ph,
                "final_success": f,
                "final_success_ci95": fh,
                "train_goal_reached": t,
                "train_goal_reached_ci95": th,
            }
        )
    return out


def methods_of(rows: list[dict]) -> list[str]:
    return sorted({r["method"] for r in rows})


def pairs_for(methods: Sequence[str], reference: str | None) -> list[tuple[str, str]]:
    """(method, reference) pairs to compare: every method against ``reference``; with None, against
    ``random_plan`` when it is there, otherwise every pair. A named reference that no run has is an
    error listing the methods found (a typo must not silently compare nothing)."""
    methods = sorted(methods)
    if reference is not None and reference not in methods:
        raise ValueError(f"--reference {reference!r} is not among the methods found: {methods}")
    ref = reference if reference is not None else (DEFAULT_REFERENCE if DEFAULT_REFERENCE in methods else None)
    if ref is None:
        return list(combinations(methods, 2))
    return [(m, ref) for m in methods if m != ref]


PAIRED_FIELDS = [
    "method",
    "reference",
    "paired_seeds",
    "diff_auc_success",
    "diff_auc_success_ci95",
    "p_success",
    "diff_auc_plan_found",
    "diff_auc_plan_found_ci95",
    "p_plan_found",
    "note",
]
PAIRED_SEED_FIELDS = [
    "method",
    "reference",
    "seed",
    "iterations",
    "auc_success",
    "auc_success_reference",
    "diff_auc_success",
    "auc_plan_found",
    "auc_plan_found_reference",
    "diff_auc_plan_found",
]


def _seed_key(seed: str) -> tuple:
    try:
        return 0, float(seed), seed
    except ValueError:
        return 1, 0.0, seed


def _ttest_p(d: np.ndarray) -> float:
    """Two-sided paired t-test p-value from the differences; nan for n < 2 or all-equal differences."""
    d = d[~np.isnan(d)]
    if len(d) < 2 or float(np.std(d, ddof=1)) == 0.0:
        return float("nan")
    return float(stats.ttest_1samp(d, 0.0).pvalue)


def paired(rows: list[dict], reference: str | None = None) -> tuple[list[dict], list[dict]]:
    """AUC differences method - reference, paired over seeds (a seed fixes the train and test problems
    for every method, so the seed-to-seed spread of problem difficulty cancels in the difference).

    Only seeds both methods ran count, and per seed only the iterations both have (a run still going
    would otherwise be compared on a shorter, lower part of its curve). Returns (one row per pair with
    mean difference, 95% Student-t CI half-width over seeds as :func:`mean_ci`, paired seeds, p-value;
    one row per pair and seed)."""
    per = _per_seed(rows)
    out, seeds_out = [], []
    for m, ref in pairs_for(list(per), reference):
        ds, dp = [], []
        for seed in sorted(set(per[m]) & set(per[ref]), key=_seed_key):
            its = sorted(set(per[m][seed]) & set(per[ref][seed]))
            if not its:
                continue
            a_s, a_p = (float(np.mean([per[m][seed][i][k] for i in its])) for k in (0, 1))
            r_s, r_p = (float(np.mean([per[ref][seed][i][k] for i in its])) for k in (0, 1))
            ds.append(a_s - r_s)
            dp.append(a_p - r_p)
            seeds_out.append(
                {
                    "method": m,
                    "reference": ref,
                    "seed": seed,
                    "iterations": len(its),
                    "auc_success": a_s,
                    "auc_success_reference": r_s,
                    "diff_auc_success": a_s - r_s,
                    "auc_plan_found": a_p,
                    "auc_plan_found_reference": r_p,
                    "diff_auc_plan_found": a_p - r_p,
                }
            )
        (s, sh), (p, ph) = mean_ci(ds), mean_ci(dp)
        n = len(ds)
        note = "no seed in common" if n == 0 else "one paired seed: no CI, not a test" if n == 1 else ""
        out.append(
            {
                "method": m,
                "reference": ref,
                "paired_seeds": n,
                "diff_auc_success": s,
                "diff_auc_success_ci95": sh,
                "p_success": _ttest_p(np.asarray(ds)),
                "diff_auc_plan_found": p,
                "diff_auc_plan_found_ci95": ph,
                "p_plan_found": _ttest_p(np.asarray(dp)),
                "note": note,
            }
        )
    return out, seeds_out


def paired_table(rows: list[dict]) -> list[str]:
    """Markdown lines; a difference from fewer than two seeds says so instead of showing ± 0."""
    if not rows:
        return ["No paired comparison: only one method in these runs."]
    lines = [
        "| method − reference | paired seeds | Δ AUC success (95% CI) | p | Δ AUC plan found (95% CI) | p |",
        "|---|---|---|---|---|---|",
    ]

    def cell(mean: float, half: float, n: int) -> str:
        if n == 0:
            return "-"
        return f"{mean:+.3f} (n=1: no CI)" if n == 1 else f"{mean:+.3f} ± {half:.3f}"

    def pval(p: float) -> str:
        return "-" if math.isnan(p) else ("< 0.001" if p < 0.001 else f"{p:.3f}")

    for r in rows:
        n = r["paired_seeds"]
        lines.append(
            f"| {r['method']} − {r['reference']} | {n} | "
            f"{cell(r['diff_auc_success'], r['diff_auc_success_ci95'], n)} | {pval(r['p_success'])} | "
            f"{cell(r['diff_auc_plan_found'], r['diff_auc_plan_found_ci95'], n)} | "
            f"{pval(r['p_plan_found'])} |"
        )
    lines.append("")
    lines.append(
        "Differences of the area under the curve, paired over the seeds both methods ran (and per seed "
        "the iterations both have); 95% Student-t CI over those seeds, p from a two-sided paired t-test. "
        "With one paired seed there is no CI and no test."
    )
    return lines


def model_only_per_seed(rows: list[dict]) -> dict[str, tuple[float, float]]:
    """seed -> (success, found) of the model alone on that seed's test problems (``model_only.csv`` rows; a
    problem found in several files, e.g. one per job of a per-method sweep, counts once: the last row wins)."""
    by_seed: dict[str, list] = defaultdict(list)
    for r in latest_rows(rows):
        by_seed[str(r["seed"])].append(r)
    return {s: model_only_rates(rs) for s, rs in by_seed.items()}


def model_only_summary(per_seed: Mapping[str, tuple[float, float]]) -> dict[str, tuple[float, float]]:
    """panel -> (mean, 95% CI half-width) over seeds of the model alone's success and plan-found rates."""
    return {
        "test_success": mean_ci([v[0] for v in per_seed.values()]),
        "test_plan_found": mean_ci([v[1] for v in per_seed.values()]),
    }


def model_only_rows(results: list[dict], per_seed: Mapping[str, tuple[float, float]]) -> list[dict]:
    """The model alone as a flat learning curve of each seed (its rates at every iteration a method of that
    seed has), so that :func:`paired` compares each method's AUC with it over the same seeds."""
    its: dict[str, set[int]] = defaultdict(set)
    for r in results:
        its[str(r["seed"])].add(int(r["iteration"]))
    return [
        {
            "method": MODEL_ONLY,
            "seed": s,
            "iteration": i,
            "test_success": per_seed[s][0],
            "test_plan_found": per_seed[s][1],
        }
        for s in per_seed
        for i in sorted(its.get(s, ()))
    ]


def load_ceiling(path: Path) -> dict:
    """The ``ceiling`` entry of a ``ladder.json`` (``python -m active.ladder``), checked, so that a wrong
    file fails here with its name rather than as a missing line in a figure."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"--ceiling {path}: no such file (expected the ladder.json of python -m active.ladder)")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"--ceiling {path}: not a JSON file ({e})") from None
    if not isinstance(data, dict) or not isinstance(data.get("ceiling"), dict):
        raise ValueError(
            f"--ceiling {path}: no 'ceiling' entry; run python -m active.ladder --rungs ceiling "
            f"(the file has {sorted(data) if isinstance(data, dict) else type(data).__name__})"
        )
    return check_ceiling(data["ceiling"], f"--ceiling {path}")


def check_ceiling(ceiling: Mapping[str, Any], where: str = "ceiling") -> dict:
    """``found`` and ``success`` must be rates in [0, 1]; ``train_trajectories`` is kept for the label."""
    c = dict(ceiling)
    for key in ("found", "success"):
        if key not in c:
            raise ValueError(f"{where}: the 'ceiling' entry has no '{key}' (has {sorted(c)})")
        v = c[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= float(v) <= 1.0:
            raise ValueError(f"{where}: ceiling.{key} = {v!r} is not a rate in [0, 1]")
    return c


def _sets(ceiling: Mapping[str, Any]) -> int:
    """How many training sets the ceiling is the mean of (``--ceiling-seeds``); 1 for a single set."""
    seeds = ceiling.get("seeds")
    return len(seeds) if isinstance(seeds, (list, tuple)) else 1


def ceiling_label(ceiling: Mapping[str, Any]) -> str:
    n = ceiling.get("train_trajectories")
    what = f"MDE on {n} trajectories" if n is not None else "MDE on target-world data"
    sets = _sets(ceiling)
    return f"ceiling ({what}, mean of {sets} sets)" if sets > 1 else f"ceiling ({what})"


def ceiling_line(ceiling: Mapping[str, Any], source: str | None = None) -> str:
    """One sentence for summary.md: the ceiling's rates and where they come from (with several training
    sets, their mean and range: one set moves the ceiling by more than the methods differ)."""
    n = ceiling.get("train_trajectories")
    fit = f"MDE fitted on {n} target-world trajectories" if n is not None else "MDE fitted on target-world data"
    n_test = f" on {ceiling['n']} test problems" if ceiling.get("n") is not None else ""
    src = f", {source}" if source else ""
    sets = _sets(ceiling)
    if sets > 1:
        ranges = {k: ceiling.get(f"{k}_range") for k in ("success", "found")}
        spread = "".join(
            f", {k} {float(r[0]):.2f}-{float(r[1]):.2f}"
            for k, r in ranges.items()
            if isinstance(r, (list, tuple)) and len(r) == 2
        )
        return (
            f"Ceiling ({fit}{src}; the mean of {sets} training sets, each{n_test}{spread}): "
            f"test success {float(ceiling['success']):.3f}, plan found {float(ceiling['found']):.3f}."
        )
    return (
        f"Ceiling ({fit}{src}): test success {float(ceiling['success']):.3f}, "
        f"plan found {float(ceiling['found']):.3f}{n_test}."
    )


class ReportError(ValueError):
    """Runs that cannot be reported together; the message names them and what differs."""


def method_config(cfg: Mapping[str, Any], method: str) -> dict:
    """What decides ``method``'s results in a run of ``cfg``, less the seed: its runs of any seed, alone or beside
    other methods, in one process or a sweep, are one curve exactly when these agree."""
    c = comparable_config(cfg)
    c.pop("seed", None)
    c["methods"] = {
        method: comparable_config({"methods": cfg.get("methods") or {}, "method": method})["methods"].get(method)
    }
    return c


def check_one_configuration_per_method(dirs: Sequence[Path]) -> None:
    """Refuse runs of one method made with different configurations (an ablation beside the default, say): merged,
    they would be reported as one curve. Runs without their ``config.json`` (committed CSVs) cannot be checked."""
    seen: dict[str, tuple[str, dict, Path]] = {}
    for d in dirs:
        d = Path(d)
        for f in [d] if d.is_file() else sorted(d.rglob("results.csv")):
            cfg_path = f.parent.parent / "config.json"
            if not cfg_path.is_file():
                continue
            try:
                cfg = json.loads(cfg_path.read_text())
            except (OSError, ValueError) as e:
                raise ReportError(f"{cfg_path} is unreadable ({e}); the runs below it cannot be checked") from None
            method = f.parent.name
            mc = method_config(cfg, method)
            key = json.dumps(mc, sort_keys=True)
            if method not in seen:
                seen[method] = (key, mc, cfg_path)
            elif seen[method][0] != key:
                a, b = flatten(seen[method][1]), flatten(mc)
                diffs = [
                    f"{k}: {a.get(k, '(absent)')!r} vs {b.get(k, '(absent)')!r}"
                    for k in sorted(set(a) | set(b))
                    if a.get(k, "(absent)") != b.get(k, "(absent)")
                ]
                raise ReportError(
                    f"{method}: runs of different configurations ({seen[method][2]} and {cfg_path}: "
                    f"{'; '.join(diffs[:8])}); report them apart (one active.report call each)"
                )


def summary_lines(summary: list[dict]) -> list[str]:
    """The summary table (markdown): per method its seeds and the means with 95 % CIs; a bound is marked as one."""
    lines = [
        "| method | seeds | AUC success (95% CI) | AUC plan found (95% CI) | final success (95% CI) "
        "| training goal reached (95% CI) |",
        "|---|---|---|---|---|---|",
    ]
    for s in summary:
        name = f"{s['method']} (bound)" if s["method"] in BOUND_NAMES else s["method"]
        lines.append(
            f"| {name} | {s['seeds']} | {s['auc_success']:.3f} ± {s['auc_success_ci95']:.3f} | "
            f"{s['auc_plan_found']:.3f} ± {s['auc_plan_found_ci95']:.3f} | "
            f"{s['final_success']:.3f} ± {s['final_success_ci95']:.3f} | "
            f"{s['train_goal_reached']:.3f} ± {s['train_goal_reached_ci95']:.3f} |"
        )
    return lines


def report(
    dirs: Sequence[Path], out: Path, reference: str | None = None, ceiling: Path | str | Mapping[str, Any] | None = None
) -> dict:
    """Figures and tables of the runs below ``dirs``; ``reference`` and ``ceiling`` (a ladder.json, or
    its ``ceiling`` entry) are checked before anything is drawn."""
    out = Path(out)
    results = collect(dirs, "results.csv")
    if not results:
        raise FileNotFoundError(f"no results.csv under {[str(d) for d in dirs]}")
    pairs_for(methods_of(results), reference)  # an unknown reference fails before any plotting
    check_one_configuration_per_method(dirs)
    ceiling_src = None
    if isinstance(ceiling, (str, Path)):
        ceiling_src, ceiling = str(ceiling), load_ceiling(Path(ceiling))
    elif ceiling is not None:
        ceiling = check_ceiling(ceiling)
    out.mkdir(parents=True, exist_ok=True)
    alone_rows = collect(dirs, MODEL_ONLY_FILE)
    alone = model_only_per_seed(alone_rows)
    alone_summary = model_only_summary(alone) if alone else None
    ceiling_lines = plot_learning_curves(results, out / "learning_curves.png", ceiling, alone_summary)
    summary = summarise(results)
    write_csv(out / "summary.csv", summary)
    pair_rows, pair_seeds = paired(results, reference)
    write_csv(out / "paired.csv", pair_rows, fields=PAIRED_FIELDS)
    write_csv(out / "paired_seeds.csv", pair_seeds, fields=PAIRED_SEED_FIELDS)
    lines = summary_lines(summary)
    if ceiling is not None:
        lines += ["", ceiling_line(ceiling, ceiling_src)]
    lines += ["", *paired_table(pair_rows)]
    alone_pairs: list[dict] = []
    if alone:
        (s, sh), (f, fh) = alone_summary["test_success"], alone_summary["test_plan_found"]
        alone_pairs, alone_seeds = paired(results + model_only_rows(results, alone), MODEL_ONLY)
        write_csv(out / "paired_model_only.csv", alone_pairs, fields=PAIRED_FIELDS)
        write_csv(out / "paired_model_only_seeds.csv", alone_seeds, fields=PAIRED_SEED_FIELDS)
        lines += [
            "",
            f"The {MODEL_ONLY}, the same test problems, planner and budget, {len(alone)} seed(s): "
            f"test success {s:.3f} ± {sh:.3f}, plan found {f:.3f} ± {fh:.3f}. Each method against it:",
            "",
            *paired_table(alone_pairs)[:-2],
        ]
    made = {
        "learning_curves": str(out / "learning_curves.png"),
        "summary": summary,
        "paired": pair_rows,
        "paired_seeds": pair_seeds,
        "ceiling": ceiling,
        "ceiling_lines": ceiling_lines,
        "model_only": alone_summary,
        "paired_model_only": alone_pairs,
    }
    tests = collect(dirs, "tests.csv")
    if tests:
        table = test_outcome_table(tests, alone_rows)
        write_csv(out / "test_outcomes.csv", table, fields=["method", "iteration", "n", *OUTCOMES])
        plot_test_outcomes(table, out / "test_outcomes.png")
        lines += ["", *test_outcome_lines(table)]
        made["test_outcomes"] = table
    cats = collect(dirs, "categories.csv")
    if cats:
        types = trajectory_type_table(cats)
        write_csv(out / "trajectory_types.csv", types, fields=["method", "iteration", "n", *CATEGORY_ORDER])
        made["trajectory_types"] = plot_trajectory_types(types, out / "trajectory_types.png")
        lines += ["", *trajectory_type_lines(types)]
    safeio.write_text(out / "summary.md", "\n".join(lines) + "\n")
    made["table"] = "\n".join(lines)
    cal = collect(dirs, "calibration.csv")
    if cal:
        plot_calibration(cal, out / "calibration.png")
    return made


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        prog="python -m active.report", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("dirs", nargs="+", type=Path, help="run or sweep directories (searched recursively)")
    ap.add_argument("--out", type=Path, default=Path("report"))
    ap.add_argument(
        "--reference",
        default=None,
        metavar="METHOD",
        help=f"method the others are compared with, paired over seeds (default: {DEFAULT_REFERENCE} "
        "when present, otherwise every pair)",
    )
    ap.add_argument(
        "--ceiling",
        type=Path,
        default=None,
        metavar="LADDER_JSON",
        help="ladder.json of python -m active.ladder: its ceiling as a dashed line and in the summary",
    )
    args = ap.parse_args(argv)
    try:
        made = report(args.dirs, args.out, reference=args.reference, ceiling=args.ceiling)
    except (ValueError, FileNotFoundError, RunFileError) as e:
        raise SystemExit(f"error: {e}") from None
    print(made["table"])
    print(f"figures in {args.out}")


if __name__ == "__main__":
    main()
