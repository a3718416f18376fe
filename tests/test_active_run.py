"""End-to-end runs of the experiment on a tiny configuration, resume after a kill, config errors."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from active.experiment import ExperimentConfig
from active.io import read_csv
from active.loop import TIMING_FIELDS
from active.run import compose_config, run_experiment

REPO = Path(__file__).resolve().parents[1]


def tiny_overrides(cache: Path) -> list[str]:
    return ["experiment=tiny", "wandb.mode=disabled", "progress=false", f"dynamics.cache_root={cache}",
            "dynamics.progress=false", "dynamics.data.n_batches=1", "dynamics.data.batch_size=2",
            "dynamics.train.max_epochs=5"]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("dynamics-cache")


@pytest.fixture(scope="module")
def straight_run(cache, tmp_path_factory):
    out = tmp_path_factory.mktemp("straight")
    cfg = compose_config(tiny_overrides(cache))
    made = run_experiment(cfg, out)
    return out, made


def _comparable(path: Path) -> list[dict]:
    return [{k: v for k, v in row.items() if k not in TIMING_FIELDS} for row in read_csv(path)]


def test_end_to_end_tiny_run_writes_everything(straight_run):
    out, made = straight_run
    for method in ("active_balanced", "random_actions"):
        rows = read_csv(out / method / "results.csv")
        assert [int(r["iteration"]) for r in rows] == [1, 2]
        assert int(rows[-1]["n_trajectories"]) == 4
        cats = read_csv(out / method / "categories.csv")
        assert len(cats) == 4
        assert {c["category"] for c in cats} <= {"successful_pour", "unsuccessful_pour", "stuck_in_plant", "other"}
        data = torch.load(out / method / "dataset.pt")
        assert data["X"].shape[1] == 8 and len(data["X"]) == len(data["y"]) == int(rows[-1]["n_transitions"])
        assert (data["y"] >= 0).all()
        assert len(read_csv(out / method / "calibration.csv")) == 2
    for fig in ("learning_curves.png", "trajectory_types.png", "calibration.png", "summary.md"):
        assert (out / "report" / fig).stat().st_size > 0
    assert {s["method"] for s in made["summary"]} == {"active_balanced", "random_actions"}
    assert (out / "config.json").exists()


def test_resume_after_kill_gives_identical_results(cache, straight_run, tmp_path):
    """Kill the real CLI with SIGKILL once the first iteration is saved, start it again, compare."""
    straight, _ = straight_run
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "active.run", *tiny_overrides(cache), f"hydra.run.dir={out}"]
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    state = out / "active_balanced" / "state.pt"
    deadline = time.time() + 300
    while not state.exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, "the run finished before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert len(read_csv(out / "active_balanced" / "results.csv")) == 1  # killed after iteration 1
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    for method in ("active_balanced", "random_actions"):
        assert _comparable(out / method / "results.csv") == _comparable(straight / method / "results.csv")
        assert read_csv(out / method / "categories.csv") == read_csv(straight / method / "categories.csv")
        a, b = torch.load(out / method / "dataset.pt"), torch.load(straight / method / "dataset.pt")
        assert torch.equal(a["X"], b["X"]) and torch.equal(a["y"], b["y"])


@pytest.mark.parametrize("override,match", [
    ("method=active_bold", "method = 'active_bold': allowed one of"),
    ("experiment.iterations=0", "experiment.iterations = 0: allowed an integer >= 1"),
    ("experiment.d_max=0", r"experiment.d_max = 0.*allowed > 0"),
    ("acquisition.gamma=1.5", r"gamma = 1.5: allowed \(0, 1\]"),
    ("acquisition._target_=nowhere.Acq", "cannot be imported"),
    ("wandb.mode=loud", "wandb.mode"),
])
def test_config_errors_before_compute(cache, tmp_path, override, match):
    cfg = compose_config(tiny_overrides(cache) + [override])
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=match):
        run_experiment(cfg, tmp_path)
    assert time.perf_counter() - t0 < 10  # nothing was simulated or trained
    assert not (tmp_path / "active_balanced").exists()


def test_experiment_config_lists_methods():
    with pytest.raises(ValueError, match="random_actions"):
        ExperimentConfig.from_mapping({"methods": ["nope"]})
    assert ExperimentConfig.from_mapping({}, method="active_mean").methods == ("active_mean",)
    assert ExperimentConfig(beta_switch_iteration=10).beta(9) == -2.0
    assert ExperimentConfig(beta_switch_iteration=10).beta(10) == 1.0
