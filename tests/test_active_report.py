"""Aggregation of runs into the summary table and figures."""

import numpy as np
import pytest

from active.io import read_csv, write_csv
from active.report import mean_ci, report


def test_mean_ci_matches_student_t_by_hand():
    m, h = mean_ci([0.2, 0.4, 0.6, 0.8])
    # t_{0.975, 3} = 3.1824; sd = 0.2582; half = 3.1824 * 0.2582 / 2
    assert m == pytest.approx(0.5)
    assert h == pytest.approx(3.18245 * np.std([0.2, 0.4, 0.6, 0.8], ddof=1) / 2, rel=1e-4)
    assert mean_ci([0.3]) == (0.3, 0.0)


def _write_run(d, method, seed, success):
    rows = [{"method": method, "seed": seed, "iteration": i + 1, "test_success": s, "test_plan_found": min(1, s + 0.1)}
            for i, s in enumerate(success)]
    write_csv(d / "results.csv", rows)
    cats = [{"method": method, "seed": seed, "iteration": 1, "category": c}
            for c in ["successful_pour", "other", "stuck_in_plant", "successful_pour"]]
    write_csv(d / "categories.csv", cats)
    write_csv(d / "calibration.csv", [{"method": method, "seed": seed, "iteration": i + 1, "coverage95": 0.9, "nll": -1.0}
                                      for i in range(len(success))])


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


def test_report_without_results_says_so(tmp_path):
    with pytest.raises(FileNotFoundError, match="no results.csv"):
        report([tmp_path], tmp_path / "rep")
