"""The admission benchmark's scoring (what share of good / bad transitions a precondition admits)."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from benchmarks.admission import run, score


class KnownMDE:
    """predict -> the given mean and std."""

    def __init__(self, mu, sd):
        self.mu, self.sd = torch.tensor(mu, dtype=torch.float64), torch.tensor(sd, dtype=torch.float64)

    def predict(self, X):
        return self.mu, self.sd


def test_shares_follow_the_test_precondition():
    # rows: good pour admitted, good pour refused (std), bad pour admitted, good move admitted, bad move refused
    data = {
        "X": torch.zeros(5, 8),
        "exp": SimpleNamespace(beta_test=2.0, d_max=0.07),
        "good": np.array([True, True, False, True, False]),
        "pour": np.array([True, True, True, False, False]),
        "partial": np.array([False, True, False, False, False]),
    }
    mde = KnownMDE([0.01, 0.01, 0.02, 0.03, 0.10], [0.01, 0.05, 0.01, 0.01, 0.01])
    r = score(mde, data)
    assert r["pour_good"] == 0.5 and r["pour_bad"] == 1.0 and r["move_good"] == 1.0 and r["move_bad"] == 0.0
    assert r["partial_good"] == 0.0 and r["partial_good_std_median"] == pytest.approx(0.05)


def test_a_directory_without_saved_mdes_is_refused_before_any_compute(tmp_path):
    with pytest.raises(FileNotFoundError, match="no seed\\*/METHOD/mde_iterNNN.pt under"):
        run([tmp_path], [tmp_path / "set.npz"], [])


def test_leave_one_set_out_needs_two_sets(tmp_path):
    from benchmarks.admission import leave_one_set_out

    with pytest.raises(ValueError, match="--leave-one-set-out needs at least 2 --sets, got 1"):
        leave_one_set_out([tmp_path / "a.npz"], [])


def test_trajectories_without_leave_one_set_out_is_refused(tmp_path, capsys):
    from benchmarks.admission import main

    with pytest.raises(SystemExit, match="2"):  # argparse's usage error
        main([str(tmp_path), "--sets", str(tmp_path / "a.npz"), "--trajectories", "8"])
    assert "--trajectories goes with --leave-one-set-out" in capsys.readouterr().err


class RecordingMDE:
    """fit -> remembers how many rows it saw (a stand-in for the config's MDE)."""

    def __init__(self, tag: str = ""):
        self.tag, self.n = tag, None

    def fit(self, X, y):
        self.n = len(y)


def test_refit_cuts_a_runs_data_at_each_iterations_transition_count(tmp_path):
    from active.io import save_torch
    from benchmarks.admission import refitted

    save_torch(tmp_path / "dataset.pt", {"X": torch.randn(12, 3), "y": torch.rand(12)})
    (tmp_path / "results.csv").write_text("iteration,n_transitions\n1,4\n2,9\n3,12\n")
    cfg = {"_target_": "tests.test_benchmarks_admission.RecordingMDE", "tag": "x"}
    fits = refitted(tmp_path, [1, 3, 7], cfg)  # iteration 7 was never completed: skipped
    assert [(it, m.n, m.tag) for it, m in fits] == [(1, 4, "x"), (3, 12, "x")]


def test_refit_without_runs_is_refused(tmp_path, capsys):
    from benchmarks.admission import main

    with pytest.raises(SystemExit, match="2"):  # argparse's usage error
        main(["--sets", str(tmp_path / "a.npz"), "--leave-one-set-out", "--refit", "4"])
    assert "--refit goes with run directories" in capsys.readouterr().err
