"""Aggregation of runs into the summary table and figures."""

import json
import math

import numpy as np
import pytest
from scipy import stats

from active.io import read_csv, write_csv
from active.report import GIVEN_PLAN, OUTCOMES, load_ceiling, main, mean_ci, paired, report


def test_mean_ci_matches_student_t_by_hand():
    m, h = mean_ci([0.2, 0.4, 0.6, 0.8])
    # t_{0.975, 3} = 3.1824; sd = 0.2582; half = 3.1824 * 0.2582 / 2
    assert m == pytest.approx(0.5)
    assert h == pytest.approx(3.18245 * np.std([0.2, 0.4, 0.6, 0.8], ddof=1) / 2, rel=1e-4)
    assert mean_ci([0.3]) == (0.3, 0.0)


def _write_run(d, method, seed, success):
    rows = [
        {"method": method, "seed": seed, "iteration": i + 1, "test_success": s, "test_plan_found": min(1, s + 0.1)}
        for i, s in enumerate(success)
    ]
    write_csv(d / "results.csv", rows)
    cats = [
        {"method": method, "seed": seed, "iteration": 1, "category": c}
        for c in ["successful_pour", "other", "stuck_in_plant", "successful_pour"]
    ]
    write_csv(d / "categories.csv", cats)
    write_csv(
        d / "calibration.csv",
        [
            {"method": method, "seed": seed, "iteration": i + 1, "coverage95": 0.9, "nll": -1.0}
            for i in range(len(success))
        ],
    )


def test_report_aggregates_seeds_and_methods(tmp_path):
    _write_run(tmp_path / "a" / "s0", "active_balanced", 0, [0.2, 0.6])
    _write_run(tmp_path / "a" / "s1", "active_balanced", 1, [0.4, 0.8])
    _write_run(tmp_path / "b", "random_plan", 0, [0.0, 0.2])
    made = report([tmp_path], tmp_path / "rep")
    summary = {s["method"]: s for s in made["summary"]}
    assert summary["active_balanced"]["seeds"] == 2
    assert summary["active_balanced"]["auc_success"] == pytest.approx(0.5)
    assert summary["random_plan"]["auc_success"] == pytest.approx(0.1)
    assert made["trajectory_types"]["random_plan"]["successful_pour"] == pytest.approx(0.5)
    for name in ("learning_curves.png", "trajectory_types.png", "calibration.png", "summary.md"):
        assert (tmp_path / "rep" / name).stat().st_size > 0
    assert len(read_csv(tmp_path / "rep" / "summary.csv")) == 2


def test_learning_curve_legend_names_each_methods_seed_count(tmp_path, monkeypatch):
    """A sweep extended for some methods only mixes seed counts on one figure: the legend says which is which."""
    import active.report as rep

    figures = []
    monkeypatch.setattr(rep.safeio, "save_figure", lambda fig, path: figures.append(fig))
    _write_run(tmp_path / "s0a", "active_admission", 0, [0.2, 0.6])
    _write_run(tmp_path / "s1a", "active_admission", 1, [0.4, 0.8])
    _write_run(tmp_path / "s0r", "random_plan", 0, [0.0, 0.2])
    rows = rep.collect([tmp_path], "results.csv")
    rep.plot_learning_curves(rows, tmp_path / "curves.png")
    labels = [t.get_text() for t in figures[0].axes[-1].get_legend().get_texts()]
    assert labels == ["active_admission (2 seeds)", "random_plan (1 seed)"]


def test_trajectory_type_table_counts_per_iteration_and_overall(tmp_path):
    from active.report import trajectory_type_table

    rows = [
        {"method": "m", "seed": "0", "iteration": "1", "category": c}
        for c in ["successful_pour", "stuck_in_plant", "stuck_in_plant", "mystery"]
    ]
    rows += [
        {"method": "m", "seed": "1", "iteration": "2", "category": c} for c in ["unsuccessful_pour", "successful_pour"]
    ]
    table = {r["iteration"]: r for r in trajectory_type_table(rows)}
    assert list(table) == ["1", "2", "all"]
    assert table["1"]["n"] == 4 and table["1"]["stuck_in_plant"] == 0.5 and table["1"]["other"] == 0.25
    assert table["all"]["n"] == 6 and table["all"]["successful_pour"] == pytest.approx(2 / 6, abs=1e-4)
    assert sum(
        table["all"][c] for c in ("successful_pour", "unsuccessful_pour", "stuck_in_plant", "other")
    ) == pytest.approx(1.0, abs=1e-3)
    _write_run(tmp_path / "a", "active_balanced", 0, [0.2, 0.6])
    report([tmp_path], tmp_path / "rep")
    csv_all = [r for r in read_csv(tmp_path / "rep" / "trajectory_types.csv") if r["iteration"] == "all"]
    assert float(csv_all[0]["successful_pour"]) == 0.5 and float(csv_all[0]["other"]) == 0.25
    assert "| active_balanced | 4 | 0.50 | 0.00 | 0.25 | 0.25 |" in (tmp_path / "rep" / "summary.md").read_text()


def test_report_without_results_says_so(tmp_path):
    with pytest.raises(FileNotFoundError, match="no results.csv"):
        report([tmp_path], tmp_path / "rep")


def _rows(method, seed, success, found):
    return [
        {
            "method": method,
            "seed": str(seed),
            "iteration": str(i + 1),
            "test_success": str(s),
            "test_plan_found": str(f),
        }
        for i, (s, f) in enumerate(zip(success, found))
    ]


def test_paired_differences_match_student_t_and_ignore_unpaired_seeds():
    # AUCs (mean over 2 iterations): A success 0.5, 0.6, 0.9 on seeds 0-2; B success 0.3, 0.5, 0.5.
    # Seed 3 only for A, seed 9 only for B: both must be ignored.
    rows = (
        _rows("A", 0, [0.4, 0.6], [1, 1])
        + _rows("A", 1, [0.5, 0.7], [1, 1])
        + _rows("A", 2, [0.8, 1.0], [1, 1])
        + _rows("A", 3, [1.0, 1.0], [1, 1])
        + _rows("B", 0, [0.2, 0.4], [0.5, 0.5])
        + _rows("B", 1, [0.5, 0.5], [1, 1])
        + _rows("B", 2, [0.4, 0.6], [0.5, 1])
        + _rows("B", 9, [0.0, 0.0], [0, 0])
    )
    pairs, seeds = paired(rows, reference="B")
    assert len(pairs) == 1
    r = pairs[0]
    d = np.array([0.2, 0.1, 0.4])
    assert (r["method"], r["reference"], r["paired_seeds"]) == ("A", "B", 3)
    assert r["diff_auc_success"] == pytest.approx(d.mean())
    half = stats.t.ppf(0.975, 2) * d.std(ddof=1) / math.sqrt(3)
    assert r["diff_auc_success_ci95"] == pytest.approx(half)
    assert r["p_success"] == pytest.approx(stats.ttest_rel([0.5, 0.6, 0.9], [0.3, 0.5, 0.5]).pvalue)
    dp = np.array([0.5, 0.0, 0.25])
    assert r["diff_auc_plan_found"] == pytest.approx(dp.mean())
    assert r["diff_auc_plan_found_ci95"] == pytest.approx(stats.t.ppf(0.975, 2) * dp.std(ddof=1) / math.sqrt(3))
    assert [s["seed"] for s in seeds] == ["0", "1", "2"]
    assert [s["diff_auc_success"] for s in seeds] == pytest.approx(list(d))


def test_paired_uses_only_iterations_both_seeds_have():
    # B's seed 0 stopped after iteration 1: A is compared on its iteration 1 only
    rows = _rows("A", 0, [0.2, 0.8], [1, 1]) + _rows("B", 0, [0.1], [1])
    (r,), (s,) = paired(rows, reference="B")
    assert s["iterations"] == 1
    assert r["diff_auc_success"] == pytest.approx(0.1)


def test_paired_default_reference_and_all_pairs():
    rows = _rows("A", 0, [0.2], [1]) + _rows("B", 0, [0.1], [1]) + _rows("random_plan", 0, [0.0], [1])
    assert {(r["method"], r["reference"]) for r in paired(rows)[0]} == {("A", "random_plan"), ("B", "random_plan")}
    rows = _rows("A", 0, [0.2], [1]) + _rows("B", 0, [0.1], [1]) + _rows("C", 0, [0.0], [1])
    assert {(r["method"], r["reference"]) for r in paired(rows)[0]} == {("A", "B"), ("A", "C"), ("B", "C")}


def test_report_writes_paired_table_and_flags_one_seed(tmp_path):
    _write_run(tmp_path / "a" / "s0", "active_balanced", 0, [0.2, 0.6])
    _write_run(tmp_path / "a" / "s1", "active_balanced", 1, [0.4, 0.8])
    _write_run(tmp_path / "b", "random_plan", 0, [0.0, 0.2])
    made = report([tmp_path], tmp_path / "rep")
    (r,) = read_csv(tmp_path / "rep" / "paired.csv")
    assert (r["method"], r["reference"], r["paired_seeds"]) == ("active_balanced", "random_plan", "1")
    assert float(r["diff_auc_success"]) == pytest.approx(0.3)
    assert float(r["diff_auc_success_ci95"]) == 0.0 and math.isnan(float(r["p_success"]))
    assert "no CI" in r["note"]
    md = (tmp_path / "rep" / "summary.md").read_text()
    assert "active_balanced − random_plan | 1 | +0.300 (n=1: no CI)" in md
    assert made["table"].strip() == md.strip()  # what main prints


def test_unknown_reference_is_refused_before_plotting(tmp_path):
    _write_run(tmp_path / "a", "active_balanced", 0, [0.2, 0.6])
    _write_run(tmp_path / "b", "random_plan", 0, [0.0, 0.2])
    with pytest.raises(
        ValueError,
        match=r"'random_actions' is not among the methods found: "
        r"\['active_balanced', 'random_plan'\]",
    ):
        report([tmp_path], tmp_path / "rep", reference="random_actions")
    assert not (tmp_path / "rep").exists()
    with pytest.raises(SystemExit, match="random_actions"):
        main([str(tmp_path), "--out", str(tmp_path / "rep"), "--reference", "random_actions"])


def _ladder(path, **entries):
    path.write_text(json.dumps({"config": {}, "seconds": 1.0, **entries}))
    return path


def _report_with_ceiling(tmp_path, ceiling: dict) -> tuple[dict, str]:
    """A one-run report drawn with the given ladder ceiling entry: (what report returns, summary.md)."""
    _write_run(tmp_path / "a", "active_balanced", 0, [0.2, 0.6])
    made = report([tmp_path / "a"], tmp_path / "rep", ceiling=_ladder(tmp_path / "ladder.json", ceiling=ceiling))
    return made, (tmp_path / "rep" / "summary.md").read_text()


def test_ceiling_line_on_success_and_plan_found_panels(tmp_path):
    made, md = _report_with_ceiling(tmp_path, {"train_trajectories": 128, "n": 30, "found": 0.9, "success": 0.7})
    label = "ceiling (MDE on 128 trajectories)"
    assert made["ceiling_lines"] == {"test_success": (0.7, label), "test_plan_found": (0.9, label)}
    assert "Ceiling (MDE fitted on 128 target-world trajectories" in md
    assert "test success 0.700, plan found 0.900 on 30 test problems" in md
    assert report([tmp_path / "a"], tmp_path / "rep2")["ceiling_lines"] == {}


def test_ceiling_over_several_training_sets_is_labelled_as_their_mean(tmp_path):
    """`--ceiling-seeds 0 1 2`: the line is the mean of three sets, and the summary gives their range."""
    made, md = _report_with_ceiling(
        tmp_path,
        {
            "train_trajectories": 128,
            "n": 30,
            "found": 0.24,
            "success": 0.2,
            "seeds": [0, 1, 2],
            "found_range": [0.07, 0.37],
            "success_range": [0.07, 0.3],
        },
    )
    label = "ceiling (MDE on 128 trajectories, mean of 3 sets)"
    assert made["ceiling_lines"] == {"test_success": (0.2, label), "test_plan_found": (0.24, label)}
    assert "the mean of 3 training sets, each on 30 test problems, success 0.07-0.30, found 0.07-0.37" in md
    assert "test success 0.200, plan found 0.240." in md


def test_ladder_without_ceiling_is_refused(tmp_path):
    ladder = _ladder(tmp_path / "ladder.json", source_model_only={"found": 0.5, "success": 0.4})
    with pytest.raises(ValueError, match=r"ladder\.json: no 'ceiling' entry"):
        load_ceiling(ladder)
    _write_run(tmp_path / "a", "active_balanced", 0, [0.2, 0.6])
    with pytest.raises(SystemExit, match="no 'ceiling' entry"):
        main([str(tmp_path / "a"), "--out", str(tmp_path / "rep"), "--ceiling", str(ladder)])
    assert not (tmp_path / "rep").exists()
    bad = _ladder(tmp_path / "bad.json", ceiling={"train_trajectories": 128, "success": 0.7})
    with pytest.raises(ValueError, match=r"bad\.json: the 'ceiling' entry has no 'found'"):
        load_ceiling(bad)


def _write_model_only(d, seed, reached, found):
    """A seed's model_only.csv (active.baseline): one row per test problem."""
    d.mkdir(parents=True, exist_ok=True)
    write_csv(
        d / "model_only.csv",
        [
            {
                "seed": seed,
                "problem": k,
                "goal": 0.4,
                "found": f,
                "goal_reached": r,
                "category": "",
                "final_spill": "",
                "digest": "x",
            }
            for k, (r, f) in enumerate(zip(reached, found))
        ],
    )


def test_model_alone_is_a_line_and_a_paired_reference(tmp_path):
    """model_only.csv beside the runs: its success and found rates, mean over seeds, as dotted lines; each
    method's AUC minus the model alone's rate, paired over the seeds that have both."""
    _write_run(tmp_path / "s0" / "ab", "active_balanced", 0, [0.2, 0.6])  # AUC 0.4
    _write_run(tmp_path / "s1" / "ab", "active_balanced", 1, [0.4, 0.8])  # AUC 0.6
    _write_run(tmp_path / "s0" / "rp", "random_plan", 0, [0.0, 0.2])  # AUC 0.1
    _write_model_only(tmp_path / "s0", 0, [True, False, False, False], [True, True, False, False])  # 0.25 / 0.5
    _write_model_only(tmp_path / "s1", 1, [True, True, False, False], [True, True, True, True])  # 0.5 / 1.0
    _write_model_only(tmp_path / "s1" / "again", 1, [True, True, False, False], [True] * 4)  # another job's copy
    made = report([tmp_path], tmp_path / "rep")
    label = "model alone (no MDE) ± 95% CI"
    assert made["ceiling_lines"] == {
        "model_only:test_success": (pytest.approx(0.375), label),
        "model_only:test_plan_found": (pytest.approx(0.75), label),
    }
    pairs = {r["method"]: r for r in made["paired_model_only"]}
    assert pairs["active_balanced"]["paired_seeds"] == 2
    assert pairs["active_balanced"]["diff_auc_success"] == pytest.approx(((0.4 - 0.25) + (0.6 - 0.5)) / 2)
    assert pairs["random_plan"]["paired_seeds"] == 1
    assert pairs["random_plan"]["diff_auc_success"] == pytest.approx(0.1 - 0.25)
    assert read_csv(tmp_path / "rep" / "paired_model_only.csv")[0]["reference"] == "model alone (no MDE)"
    md = (tmp_path / "rep" / "summary.md").read_text()
    assert "model alone (no MDE), the same test problems, planner and budget, 2 seed(s): test success 0.375" in md
    assert "| active_balanced − model alone (no MDE) | 2 | +0.125" in md
    # the usual comparison is unchanged by the reference
    assert {(r["method"], r["reference"]) for r in made["paired"]} == {("active_balanced", "random_plan")}


def test_no_model_only_file_no_line(tmp_path):
    _write_run(tmp_path / "a", "active_balanced", 0, [0.2, 0.6])
    made = report([tmp_path / "a"], tmp_path / "rep")
    assert made["model_only"] is None and made["paired_model_only"] == []
    assert not (tmp_path / "rep" / "paired_model_only.csv").exists()


def _write_tests(d, method, seed, outcomes):
    """tests.csv of one run: ``outcomes`` per iteration, one (found, goal_reached, category) per problem."""
    rows = [
        {
            "method": method,
            "seed": seed,
            "iteration": it + 1,
            "problem": k,
            "goal": 0.4,
            "found": f,
            "goal_reached": g,
            "category": c,
            "final_spill": 0.0 if f else "",
        }
        for it, probs in enumerate(outcomes)
        for k, (f, g, c) in enumerate(probs)
    ]
    write_csv(d / "tests.csv", rows)


def test_test_outcomes_table_figure_and_summary(tmp_path):
    """tests.csv beside the runs: per method and iteration the share of each outcome (a found plan's failure
    by its trajectory category), over seeds; the model alone's outcomes beside them; a row seen twice counts once."""
    ok, miss = (True, True, "successful_pour"), (False, False, "")
    stuck, spill, short = (
        (True, False, "stuck_in_plant"),
        (True, False, "unsuccessful_pour"),
        (True, False, "successful_pour"),
    )
    _write_run(tmp_path / "s0" / "ab", "active_balanced", 0, [0.5, 0.5])
    _write_tests(tmp_path / "s0" / "ab", "active_balanced", 0, [[ok, miss], [ok, stuck]])
    _write_run(tmp_path / "s1" / "ab", "active_balanced", 1, [0.0, 0.5])
    _write_tests(tmp_path / "s1" / "ab", "active_balanced", 1, [[spill, short], [ok, miss]])
    _write_tests(tmp_path / "s1" / "copy", "active_balanced", 1, [[spill, short], [ok, miss]])  # another job's copy
    _write_model_only(tmp_path / "s0", 0, [True, False], [True, True])
    made = report([tmp_path], tmp_path / "rep")
    rows = {(r["method"], r["iteration"]): r for r in made["test_outcomes"]}
    it1 = rows[("active_balanced", "1")]
    assert it1["n"] == 4
    assert (it1["goal_reached"], it1["no_plan_found"], it1["spilled"], it1["clean_pour_wrong_amount"]) == (0.25,) * 4
    everything = rows[("active_balanced", "all")]
    assert everything["n"] == 8 and everything["goal_reached"] == 0.375 and everything["stuck_in_plant"] == 0.125
    alone = rows[("model alone (no MDE)", "all")]
    assert alone["n"] == 2 and alone["goal_reached"] == 0.5 and alone["no_plan_found"] == 0.0
    assert sum(alone[o] for o in OUTCOMES) == pytest.approx(1.0)
    assert alone[GIVEN_PLAN] == 0.5 and everything[GIVEN_PLAN] == pytest.approx(0.375 / 0.75)
    assert rows[("active_balanced", "2")][GIVEN_PLAN] == pytest.approx(2 / 3, abs=1e-4)
    assert (tmp_path / "rep" / "test_outcomes.png").stat().st_size > 0
    assert len(read_csv(tmp_path / "rep" / "test_outcomes.csv")) == len(made["test_outcomes"])
    md = (tmp_path / "rep" / "summary.md").read_text()
    assert "| active_balanced | 8 | 0.38 |" in md and "| model alone (no MDE) | 2 | 0.50 |" in md
    assert "| 0.00 | 0.25 | 0.50 |" in md  # active_balanced: other 0, no plan found 0.25, goal reached given a plan 0.5


def test_no_tests_file_no_outcome_figure(tmp_path):
    _write_run(tmp_path / "a", "active_balanced", 0, [0.2, 0.6])
    made = report([tmp_path / "a"], tmp_path / "rep")
    assert "test_outcomes" not in made and not (tmp_path / "rep" / "test_outcomes.png").exists()


def test_each_method_has_one_colour_in_every_figure_and_curves_run_over_trajectories(tmp_path, monkeypatch):
    """random_plan is the same colour in a report of two methods and in one of four; the x-axis is the number of
    training trajectories executed (the data active learning is about), and every figure comes as PNG and PDF."""
    import matplotlib.colors as mcolors

    import active.report as rep

    figures = []
    real = rep.safeio.save_figure
    monkeypatch.setattr(rep.safeio, "save_figure", lambda fig, path: (figures.append(fig), real(fig, path)))

    def colour_of(methods, out):
        for k, m in enumerate(methods):
            d = out / m
            d.mkdir(parents=True)
            write_csv(
                d / "results.csv",
                [
                    {
                        "method": m,
                        "seed": 0,
                        "iteration": i + 1,
                        "n_trajectories": 6 * (i + 1),
                        "test_success": 0.1 * k,
                        "test_plan_found": 0.5,
                    }
                    for i in range(3)
                ],
            )
        figures.clear()
        report([out], out / "rep")
        ax = figures[0].axes[0]
        lines = {ln.get_label().split(" (")[0]: ln for ln in ax.get_lines() if "seed" in ln.get_label()}
        assert list(lines["random_plan"].get_xdata()) == [6, 12, 18] and "trajectories" in ax.get_xlabel()
        assert (out / "rep" / "learning_curves.pdf").stat().st_size > 0
        return mcolors.to_hex(lines["random_plan"].get_color())

    two = colour_of(["active_balanced", "random_plan"], tmp_path / "two")
    four = colour_of(["active_admission", "active_balanced", "model_plan", "random_plan"], tmp_path / "four")
    assert two == four == rep.METHOD_COLOURS["random_plan"].lower()
    assert rep.method_colour("my_method") == rep.method_colour("my_method") in rep.FALLBACK_COLOURS


def test_runs_of_one_method_with_different_configurations_are_refused(tmp_path):
    """An ablation beside the default, reported together, would be one curve: refused naming both folders and
    what differs; seeds and the other methods of a run may differ."""
    from active.report import ReportError
    from active.run import compose_config

    def run(folder, overrides, seed):
        d = tmp_path / folder
        (d / "random_plan").mkdir(parents=True)
        (d / "config.json").write_text(json.dumps(compose_config(["experiment=tiny", f"seed={seed}", *overrides])))
        _write_run(d / "random_plan", "random_plan", seed, [0.2, 0.4])

    run("default0", [], 0)
    run("default1", ["method=random_plan"], 1)
    assert report([tmp_path / "default0", tmp_path / "default1"], tmp_path / "ok")["summary"][0]["seeds"] == 2
    run("ablation", ["mde.label_max=0.15"], 2)
    with pytest.raises(
        ReportError, match=r"random_plan: runs of different configurations .*mde.label_max: 0.15 vs 0.1"
    ):
        report([tmp_path], tmp_path / "rep")


def test_p_values_below_a_thousandth_are_written_as_such():
    from active.report import paired_table

    row = {
        "method": "a",
        "reference": "b",
        "paired_seeds": 40,
        "diff_auc_success": 0.1,
        "diff_auc_success_ci95": 0.02,
        "p_success": 1e-6,
        "diff_auc_plan_found": 0.0,
        "diff_auc_plan_found_ci95": 0.01,
        "p_plan_found": 0.5,
    }
    text = "\n".join(paired_table([row]))
    assert "| < 0.001 |" in text and "| 0.000 |" not in text


def test_a_bound_is_marked_as_one_in_the_summary_and_is_never_the_runs_headline():
    """The oracle (active.oracle) bounds what any choice among the candidates can reach: the summary table names it
    a bound, and the headline a sweeper optimises is the best method's AUC, not the bound's."""
    from active.report import summary_lines
    from active.run import headline

    keys = ("auc_success", "auc_plan_found", "final_success", "train_goal_reached")
    row = {**{k: 0.5 for k in keys}, **{f"{k}_ci95": 0.1 for k in keys}, "seeds": 3}
    lines = summary_lines([{**row, "method": "oracle"}, {**row, "method": "random_plan"}])
    assert lines[2].startswith("| oracle (bound) | 3 |") and lines[3].startswith("| random_plan | 3 |")
    made = {"summary": [{"method": "oracle", "auc_success": 0.9}, {"method": "random_plan", "auc_success": 0.6}]}
    assert headline(made) == 0.6
    assert headline({"summary": [{"method": "oracle", "auc_success": 0.9}]}) is None
