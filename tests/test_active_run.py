"""End-to-end runs of the experiment on a tiny configuration: resume after a kill, config errors before
compute, and run integrity (one writer per directory, reuse checks, damaged files, permissions)."""

import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

import safeio
from active.experiment import ExperimentConfig
from active.identity import RUN_FORMAT_VERSION, config_digest
from active.io import RunFileError, load_checked, read_csv, write_csv
from active.loop import TIMING_FIELDS
from active.run import compose_config, run_experiment
from active.runlock import RunDirectoryError, read_owner

REPO = Path(__file__).resolve().parents[1]


def tiny_overrides(cache: Path) -> list[str]:
    return [
        "experiment=tiny",
        "wandb.mode=disabled",
        "progress=false",
        f"dynamics.cache_root={cache}",
        "dynamics.progress=false",
        "dynamics.data.n_batches=1",
        "dynamics.data.batch_size=2",
        "dynamics.data.pour_batches=0",
        "dynamics.train.max_epochs=5",
    ]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("dynamics-cache")


@pytest.fixture(scope="module")
def straight_run(cache, tmp_path_factory):
    out = tmp_path_factory.mktemp("straight")
    cfg = compose_config(tiny_overrides(cache) + ["runner=sequential"])  # the CLI's default is lockstep
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
        # one row per test problem and iteration; its shares are the results' rates
        tests = read_csv(out / method / "tests.csv")
        n_test = len(tests) // 2
        assert n_test > 0 and [int(r["iteration"]) for r in tests] == [1] * n_test + [2] * n_test
        for row in rows:
            mine = [r for r in tests if r["iteration"] == row["iteration"]]
            assert [int(r["problem"]) for r in mine] == list(range(n_test))
            assert sum(r["goal_reached"] == "True" for r in mine) / n_test == pytest.approx(float(row["test_success"]))
            assert sum(r["found"] == "True" for r in mine) / n_test == pytest.approx(float(row["test_plan_found"]))
            assert all(r["category"] == "" for r in mine if r["found"] == "False")
    for fig in ("learning_curves.png", "trajectory_types.png", "calibration.png", "test_outcomes.png", "summary.md"):
        assert (out / "report" / fig).stat().st_size > 0
    assert {s["method"] for s in made["summary"]} == {"active_balanced", "random_actions"}
    assert (out / "config.json").exists()
    # the model alone on the same test problems, once per seed, tagged with the config that made it
    alone = read_csv(out / "model_only.csv")
    cfg = json.loads((out / "config.json").read_text())
    assert [int(r["problem"]) for r in alone] == list(range(int(cfg["experiment"]["test_problems"])))
    assert {r["digest"] for r in alone} == {config_digest(cfg)}
    assert all(r["found"] == "True" or r["goal_reached"] == "False" for r in alone)  # success needs a plan
    assert made["model_only"] is not None and (out / "report" / "paired_model_only.csv").exists()


@pytest.fixture(scope="module")
def wheel_python(tmp_path_factory) -> str:
    """An interpreter that imports the project from a built wheel (installed into a folder of its own) and its
    dependencies from this interpreter's environment."""
    import tomllib

    if os.name != "posix":
        pytest.skip("the wheel's interpreter is a POSIX shell script here")
    root = tmp_path_factory.mktemp("wheel")
    src, wheels, venv = (root / d for d in ("src", "wheels", "venv"))
    src.mkdir()
    # the project's files only: a build/ folder left in the checkout would put stale files into the wheel
    packages = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]["include"]
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, src / name)
    for name in (p.rstrip("*") for p in packages):
        shutil.copytree(REPO / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    quiet = dict(check=True, capture_output=True, text=True)
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(wheels), str(src)],
        cwd=src,
        **quiet,
    )
    # the wheel into a folder of its own, ahead of everything else on the path of this very interpreter: the
    # dependencies are this environment's (a virtual environment, a conda environment or the system
    # interpreter), the project's packages the wheel's (a venv made from here would see the base interpreter's)
    site = venv / "site-packages"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "-q",
            "--no-deps",
            "--target",
            str(site),
            *map(str, wheels.glob("*.whl")),
        ],
        **quiet,
    )
    py = venv / "bin" / "python"
    py.parent.mkdir(parents=True)
    py.write_text(f'#!/bin/sh\nPYTHONPATH="{site}" exec "{sys.executable}" "$@"\n')
    py.chmod(0o755)
    return str(py)


def _wheel_env() -> dict:
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    env.pop("PYTHONPATH", None)
    return env


def test_a_built_wheel_finds_its_configs_and_shipped_files_outside_the_repository(cache, wheel_python, tmp_path):
    """The configs and the default model's shipped data and members are package data: a wheel, run from a
    folder that is not the repository, composes the experiment's config (Hydra's --cfg job) and finds the
    shipped files inside itself. The same CLI runs the experiment in the kill-and-resume test below."""
    work = tmp_path / "elsewhere"
    work.mkdir()
    quiet = dict(check=True, capture_output=True, text=True, env=_wheel_env(), cwd=work)
    venv = str(Path(wheel_python).parents[1])
    where = subprocess.run(
        [
            wheel_python,
            "-c",
            "import active, configs, dynamics.train as s; print(active.__file__); "
            "print(configs.CONFIG_DIR); print(s.SHIPPED_DIR)",
        ],
        **quiet,
    ).stdout.split()
    assert len(where) == 3 and all(w.startswith(venv) for w in where), where  # the wheel, not the checkout
    shipped = sorted(p.name for p in Path(where[2]).glob("*.pt"))
    assert shipped == sorted(p.name for p in (REPO / "dynamics" / "shipped").glob("*.pt")), shipped
    job = subprocess.run(
        [wheel_python, "-m", "active.run", *tiny_overrides(cache), "--cfg", "job", "--resolve"], **quiet
    ).stdout
    want = compose_config(tiny_overrides(cache))
    assert f"iterations: {want['experiment']['iterations']}" in job and str(cache) in job


@pytest.mark.slow  # one more tiny run, ~60 s on 2 cores; the test above checks what the wheel ships
def test_a_built_wheel_runs_the_tiny_experiment_outside_the_repository(cache, straight_run, wheel_python, tmp_path):
    """The wheel's CLI, run from a folder that is not the repository, gives the editable install's results."""
    straight, _ = straight_run
    work = tmp_path / "elsewhere"
    work.mkdir()
    out = tmp_path / "run"
    subprocess.run(
        [wheel_python, "-m", "active.run", *tiny_overrides(cache), f"hydra.run.dir={out}"],
        cwd=work,
        env=_wheel_env(),
        check=True,
        capture_output=True,
        text=True,
    )
    for method in ("active_balanced", "random_actions"):
        assert _comparable(out / method / "results.csv") == _comparable(straight / method / "results.csv")
    assert (out / "report" / "learning_curves.png").stat().st_size > 0


def test_resume_after_kill_gives_identical_results(cache, straight_run, tmp_path):
    """Kill the real CLI with SIGKILL once the first iteration is saved, start it again, compare. The CLI
    runs in lockstep (its default) and the straight run sequentially: the same results either way."""
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
    assert read_owner(out)["pid"] == proc.pid  # its lock record survives it ...
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"from pid {proc.pid}" in done.stdout + done.stderr  # ... and the rerun took the lock over
    assert read_owner(out) is None  # released at the end
    for method in ("active_balanced", "random_actions"):
        assert _comparable(out / method / "results.csv") == _comparable(straight / method / "results.csv")
        for name in ("categories.csv", "tests.csv"):
            assert read_csv(out / method / name) == read_csv(straight / method / name)
        a, b = torch.load(out / method / "dataset.pt"), torch.load(straight / method / "dataset.pt")
        assert torch.equal(a["X"], b["X"]) and torch.equal(a["y"], b["y"])
    assert read_csv(out / "model_only.csv") == read_csv(straight / "model_only.csv")


def _same_run(a: Path, b: Path) -> None:
    """Two run directories hold the same results (timing columns aside), method by method."""
    for method in ("active_balanced", "random_actions"):
        assert _comparable(a / method / "results.csv") == _comparable(b / method / "results.csv")
        for name in ("categories.csv", "calibration.csv", "tests.csv"):
            assert read_csv(a / method / name) == read_csv(b / method / name)
        x, y = torch.load(a / method / "dataset.pt"), torch.load(b / method / "dataset.pt")
        assert torch.equal(x["X"], y["X"]) and torch.equal(x["y"], y["y"])


@pytest.mark.slow  # ~60 s; in CI the CLI runs of the kill and wheel tests (default runner: lockstep) check the same
def test_lockstep_gives_the_results_of_the_sequential_run(cache, straight_run, tmp_path):
    """runner=lockstep: both methods share each round's planning batch and simulation (random_actions,
    which does not plan, joins the other's simulation); the results are the sequential run's, bit for bit."""
    straight, _ = straight_run
    out = tmp_path / "lockstep"
    run_experiment(compose_config(tiny_overrides(cache) + ["planner.workers=1", "runner=lockstep"]), out)
    _same_run(out, straight)


@pytest.mark.slow  # two more tiny runs, one of two seeds: ~140 s on 2 cores
def test_lockstep_over_methods_and_seeds_gives_the_results_of_each_run_alone(cache, straight_run, tmp_path):
    """runner=lockstep with seeds [0, 3]: both methods of both seeds share each round's planning batch and
    simulation (random_actions, which does not plan, joins the others' simulation). Seed 0's folder was
    started by a single-seed run that finished one iteration of active_balanced only (a kill between
    two runs' saves looks the same: every save is atomic), so lockstep resumes each run from its own
    iteration. Seed 0 ends with the sequential run's results bit for bit; report/ covers both seeds."""
    straight, _ = straight_run
    out = tmp_path / "lockstep"
    tiny = tiny_overrides(cache) + ["planner.workers=1"]  # the straight run planned in 2 processes where it could
    run_experiment(compose_config(tiny + ["method=active_balanced", "experiment.iterations=1"]), out / "seed0")
    assert not (out / "seed0" / "random_actions").exists()
    made = run_experiment(compose_config(tiny + ["runner=lockstep", "seeds=[0,3]"]), out)
    _same_run(out / "seed0", straight)
    assert [int(r["iteration"]) for r in read_csv(out / "seed3" / "random_actions" / "results.csv")] == [1, 2]
    assert {(s["method"], s["seeds"]) for s in made["summary"]} == {("active_balanced", 2), ("random_actions", 2)}
    assert (out / "report" / "learning_curves.png").stat().st_size > 0
    assert json.loads((out / "seed3" / "config.json").read_text())["seed"] == 3


@pytest.mark.parametrize(
    "override,match",
    [
        ("runner=parallel", r"runner = 'parallel': allowed one of \('sequential', 'lockstep'\)"),
        ("seeds=[0,0]", r"seeds = \[0, 0\]: allowed each seed at most once"),
        ("seeds=[1,-2]", r"seeds\[1\] = -2: allowed an integer"),
        ("seeds=[]", r"seeds = \[\]: allowed null"),
    ],
)
def test_runner_and_seeds_errors_before_compute(cache, tmp_path, override, match):
    with pytest.raises(ValueError, match=match):
        run_experiment(compose_config(tiny_overrides(cache) + [override]), tmp_path / "bad")
    assert not (tmp_path / "bad").exists()


@pytest.mark.slow  # one more tiny run, ~40 s on 2 cores; tests/test_planner_pool.py checks the pool itself by default
def test_planner_workers_do_not_change_results(cache, straight_run, tmp_path):
    """The straight run planned with planner.workers=auto; another process count gives the same results."""
    from planner.pool import resolve_workers

    straight, _ = straight_run
    other = 1 if resolve_workers("auto") > 1 else 2
    out = tmp_path / f"workers{other}"
    run_experiment(compose_config(tiny_overrides(cache) + [f"planner.workers={other}", "runner=sequential"]), out)
    _same_run(out, straight)


@pytest.mark.slow  # another tiny run (the mechanism itself: tests/test_planner_pool.py, in CI)
def test_a_plan_that_raises_is_recorded_and_the_run_goes_on(cache, straight_run, tmp_path, monkeypatch, caplog):
    """One planner run in two raises: the run finishes, the failures are counted (plan_errors) and logged."""
    import planner.rrt

    real, calls = planner.rrt.Planner.plan, []

    def flaky(self, *args, **kwargs):
        calls.append(1)
        if len(calls) % 2 == 0:
            raise RuntimeError("simulated planner failure")
        return real(self, *args, **kwargs)

    monkeypatch.setattr(planner.rrt.Planner, "plan", flaky)  # in-process planning: planner.workers=1
    out = tmp_path / "flaky"
    run_experiment(compose_config(tiny_overrides(cache) + ["planner.workers=1"]), out)
    rows = read_csv(out / "active_balanced" / "results.csv")
    assert [int(r["iteration"]) for r in rows] == [1, 2]
    assert sum(int(r["plan_errors"]) for r in rows) > 0
    assert "simulated planner failure" in caplog.text


@pytest.mark.parametrize(
    "override,match",
    [
        ("method=active_bold", "method = 'active_bold': allowed one of"),
        ("experiment.iterations=0", "experiment.iterations = 0: allowed an integer >= 1"),
        ("experiment.d_max=0", r"experiment.d_max = 0.*allowed > 0"),
        ("acquisition.gamma=1.5", r"gamma = 1.5: allowed \(0, 1\]"),
        ("acquisition._target_=nowhere.Acq", "cannot be imported"),
        ("+acquisition.form=lcb", r"acquisition.form = 'lcb': not a parameter of active.acquisition.DiscountedMaxUCB"),
        ("wandb.mode=loud", "wandb.mode"),
        ("seed=-1", r"^seed = -1: allowed an integer in \[0, 4294967295\]$"),
        ("world.sim.dx=0.05", r"world.sim.dx = 0.05: too coarse for the geometry.*Allowed: 0 < dx <= 0.01 m"),
    ],
)
def test_config_errors_before_compute(cache, tmp_path, override, match):
    cfg = compose_config(tiny_overrides(cache) + [override])
    cached = sorted(cache.rglob("*"))
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=match):
        run_experiment(cfg, tmp_path)
    assert time.perf_counter() - t0 < 10  # nothing was simulated or trained
    assert not (tmp_path / "active_balanced").exists()
    assert sorted(cache.rglob("*")) == cached  # no data generated, no (degenerate) model cached


def test_unwritable_method_directory_fails_before_compute(cache, tmp_path):
    (tmp_path / "random_actions").write_text("a file where the second method's directory belongs")
    t0 = time.perf_counter()
    with pytest.raises(RunDirectoryError, match=r"output directory .*random_actions is not writable"):
        run_experiment(compose_config(tiny_overrides(cache)), tmp_path)
    assert time.perf_counter() - t0 < 10
    assert not (tmp_path / "config.json").exists() and not (tmp_path / "calibration_set.pt").exists()
    assert read_owner(tmp_path) is None  # the lock was released


@pytest.mark.slow  # ~25 s on 2 cores; tests/test_run_integrity.py checks the lock with two processes by default
def test_second_writer_is_refused_while_the_first_runs(cache, straight_run, tmp_path):
    """Two real CLI processes into one directory: the second (another seed) stops before doing anything."""
    out = tmp_path / "shared"
    cmd = [sys.executable, "-m", "active.run", *tiny_overrides(cache), f"hydra.run.dir={out}"]
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    first = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 300
        while not (out / "config.json").exists() and first.poll() is None and time.time() < deadline:
            time.sleep(0.05)
        second = subprocess.run(cmd + ["seed=1"], cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
        assert first.poll() is None, "the first run ended before the second was refused: nothing was tested"
    finally:
        first.kill()
        first.wait()
    assert second.returncode != 0
    assert f"is in use by another run: pid {first.pid}" in second.stderr, second.stderr[-2000:]
    assert json.loads((out / "config.json").read_text())["seed"] == 0  # still the first run's record


def _copy_run(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def test_result_files_get_the_umask_permissions(straight_run):
    out, _ = straight_run
    expected = 0o666 & ~safeio.current_umask()
    files = [p for p in out.rglob("*") if p.is_file() and "wandb" not in p.parts]
    assert {p.name for p in files} >= {
        "config.json",
        "calibration_set.pt",
        "results.csv",
        "state.pt",
        "mde_iter002.pt",
        "learning_curves.png",
        "run.lock",
    }
    assert {
        str(p.relative_to(out)): oct(stat.S_IMODE(p.stat().st_mode))
        for p in files
        if stat.S_IMODE(p.stat().st_mode) != expected
    } == {}


def test_refused_rerun_leaves_the_directory_as_it_was(cache, straight_run, tmp_path):
    out = _copy_run(straight_run[0], tmp_path / "run")
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    t0 = time.perf_counter()
    with pytest.raises(RunDirectoryError, match=r"holds results of a different configuration.*seed: 0 -> 1"):
        run_experiment(compose_config(tiny_overrides(cache) + ["seed=1"]), out)
    assert time.perf_counter() - t0 < 10
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before  # config.json included


def test_moved_cache_and_leftovers_do_not_stop_a_finished_run(cache, straight_run, tmp_path):
    """The cache moved (its location is not part of the digest), and temporary files of a kill."""
    out = _copy_run(straight_run[0], tmp_path / "run")
    moved = _copy_run(cache, tmp_path / "moved-cache")
    orphans = [out / ".calibration_set.pt.123.abcd.tmp", out / "random_actions" / ".results.csv.9.ef01.tmp"]
    for p in orphans:
        p.write_bytes(b"half a file")
    models = {p: p.stat().st_mtime_ns for p in moved.rglob("model.pt")}
    cfg = compose_config(tiny_overrides(moved))
    run_experiment(cfg, out)
    assert {p: p.stat().st_mtime_ns for p in moved.rglob("model.pt")} == models  # nothing retrained
    assert not any(p.exists() for p in orphans)
    for method in ("active_balanced", "random_actions"):
        assert read_csv(out / method / "results.csv") == read_csv(straight_run[0] / method / "results.csv")
    assert json.loads((out / "config.json").read_text())["dynamics"]["cache_root"] == str(moved)


def test_model_alone_is_measured_once_and_rebuilt_for_another_config(cache, straight_run, tmp_path, monkeypatch):
    """A finished run started again reuses its model_only.csv; one tagged by another config is rebuilt
    (with the same rows: the reference is determined by the config), and no method's results change."""
    import active.baseline

    out = _copy_run(straight_run[0], tmp_path / "run")
    cfg = compose_config(tiny_overrides(cache))
    real, calls = active.baseline.measure, []

    def counted(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(active.baseline, "measure", counted)
    run_experiment(cfg, out)
    assert calls == []
    rows = read_csv(out / "model_only.csv")
    write_csv(out / "model_only.csv", [{**r, "digest": "0123456789abcdef"} for r in rows])
    run_experiment(cfg, out)
    assert calls == [1]
    assert read_csv(out / "model_only.csv") == rows
    for method in ("active_balanced", "random_actions"):
        assert read_csv(out / method / "results.csv") == read_csv(straight_run[0] / method / "results.csv")


@pytest.mark.parametrize(
    "name,damage,match",
    [
        (
            "active_balanced/mde_iter002.pt",
            "truncate",
            r"mde_iter002.pt is damaged \(its bytes do not match the checksum",
        ),
        ("random_actions/mde_iter002.pt", "garbage", r"mde_iter002.pt is damaged .*redo this method from iteration 1"),
        ("calibration_set.pt", "truncate", r"calibration_set.pt is unreadable .*it is rebuilt from the configuration"),
        (
            "random_actions/state.pt",
            "garbage",
            r"state.pt is unreadable .*results.csv, tests.csv beside it are intact and kept",
        ),
    ],
)
def test_damaged_run_files_are_named_with_the_fix(cache, straight_run, tmp_path, name, damage, match):
    out = _copy_run(straight_run[0], tmp_path / "run")
    path = out / name
    path.write_bytes(path.read_bytes()[:300] if damage == "truncate" else b"garbage " * 50)
    t0 = time.perf_counter()
    with pytest.raises(RunFileError, match=match) as e:
        run_experiment(compose_config(tiny_overrides(cache)), out)
    assert str(path) in str(e.value) and "weights_only" not in str(e.value)
    assert time.perf_counter() - t0 < 30  # before any simulation


def test_stale_calibration_set_of_another_seed_is_not_reused(cache, straight_run, tmp_path, monkeypatch):
    """A seed-0 run killed before its first iteration left its calibration set; a seed-1 run rebuilds it."""
    import active.run

    out = tmp_path / "run"
    out.mkdir()
    for name in ("config.json", "calibration_set.pt"):
        shutil.copy(straight_run[0] / name, out / name)
    made, seen = [], []

    def fake_calibration(world, dyn, executor, sampler, n, length, seed):
        made.append(seed)
        return {"X": torch.zeros(1, 8, dtype=torch.float64), "y": torch.full((1,), float(seed), dtype=torch.float64)}

    class NoLoop:  # the methods are not what this test is about (runner=sequential: each run's run())
        def __init__(self, ctx, method, make_mde, make_acq, tracker):
            seen.append(ctx.calibration)
            self.tracker = tracker

        def run(self):
            return []

    monkeypatch.setattr(active.run, "make_calibration_set", fake_calibration)
    monkeypatch.setattr(active.run, "MethodRun", NoLoop)
    monkeypatch.setattr(active.run, "report", lambda dirs, o: {"table": ""})
    cfg = compose_config(tiny_overrides(cache) + ["seed=1", "runner=sequential"])
    run_experiment(cfg, out)
    assert made == [1] and all(float(c["y"][0]) == 1.0 for c in seen)
    saved = load_checked(out / "calibration_set.pt")
    assert saved["digest"] == config_digest(cfg) and float(saved["y"][0]) == 1.0
    assert json.loads((out / "config.json").read_text())["seed"] == 1


@pytest.mark.slow
def test_stale_calibration_set_rerun_equals_a_fresh_run(cache, straight_run, tmp_path):
    """The probe's case end to end: calibration.csv of the rerun equals a fresh seed-1 run's."""
    cfg = compose_config(tiny_overrides(cache) + ["seed=1"])
    run_experiment(cfg, tmp_path / "fresh")
    out = tmp_path / "stale"
    out.mkdir()
    for name in ("config.json", "calibration_set.pt"):
        shutil.copy(straight_run[0] / name, out / name)
    run_experiment(cfg, out)
    for method in ("active_balanced", "random_actions"):
        assert read_csv(out / method / "calibration.csv") == read_csv(tmp_path / "fresh" / method / "calibration.csv")


def test_state_of_another_run_format_is_refused_naming_both_versions(cache, straight_run, tmp_path):
    """A run directory written by another run format version is refused before any compute, with both versions
    and how to rerun in the message; nothing in it changes."""
    out = _copy_run(straight_run[0], tmp_path / "run")
    state_path = out / "active_balanced" / "state.pt"
    st = load_checked(state_path)
    del st["format"], st["version"]  # as the first run format wrote it: a plain torch file without them
    safeio.save_torch(state_path, st)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    with pytest.raises(
        RunFileError,
        match=rf"run format version 1; this code reads version {RUN_FORMAT_VERSION}"
        r".*hydra\.run\.dir",
    ):
        run_experiment(compose_config(tiny_overrides(cache)), out)
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


def test_experiment_config_lists_methods():
    with pytest.raises(ValueError, match="random_actions"):
        ExperimentConfig.from_mapping({"methods": ["nope"]})
    assert ExperimentConfig.from_mapping({}, method="active_mean").methods == ("active_mean",)
    assert ExperimentConfig(beta_switch_iteration=10).beta(9) == -2.0
    assert ExperimentConfig(beta_switch_iteration=10).beta(10) == 1.0


def test_model_plan_method_plans_its_candidates_without_the_mde():
    """model_plan chooses like random_plan, among candidates the planner found with the model alone: its planning
    need carries no MDE whatever the run's MDE is, random_plan's carries the run's; requests are otherwise the same
    (kind, beta, seeds by (seed, method, iteration, problem))."""
    from types import SimpleNamespace

    import numpy as np

    from active.loop import MethodRun
    from active.methods import ModelPlan, RandomPlan, build_method
    from active.needs import PlanNeed
    from active.seeds import derive_seed
    from task.problems import Problem

    assert isinstance(build_method("model_plan"), ModelPlan) and isinstance(build_method("model_plan"), RandomPlan)
    probs = [Problem(start=np.array([0.3 + 0.01 * k, 0.2, 0.0, 1.0, 0.0]), goal=0.4) for k in range(2)]
    mde = object()  # the run's fitted MDE (only passed on, never called here)

    def need_of(method: str) -> PlanNeed:
        run = SimpleNamespace(
            ctx=SimpleNamespace(exp=ExperimentConfig(), seed=7), method=method, plan_errors=0, spec=build_method(method)
        )
        return next(MethodRun._plan_chunk(run, probs, mde, 2, 0, 1.0))

    mine, theirs = need_of("model_plan"), need_of("random_plan")
    assert isinstance(mine, PlanNeed) and mine.mde is None and theirs.mde is mde
    assert [(r.kind, r.beta, r.goal) for r in mine.requests] == [(r.kind, r.beta, r.goal) for r in theirs.requests]
    assert [r.seed for r in mine.requests] == [derive_seed(7, "plan", 2, j) for j in range(2)]
    assert [r.seed for r in mine.requests] == [r.seed for r in theirs.requests]  # common random numbers


def test_model_plan_fallback_replaces_refused_rounds_by_plans_of_the_model_alone():
    """experiment.fallback=model_plan: only the problems whose candidates were all refused get a planner call,
    in one batch and with no MDE (seeded by (seed, method, iteration, problem)); a found plan replaces the random
    actions (source "fallback_plan"), a search that finds nothing leaves them; random_actions changes nothing."""
    from types import SimpleNamespace

    import numpy as np

    from active.loop import MethodRun
    from active.methods import Choice
    from active.needs import PlanNeed
    from active.seeds import derive_seed
    from task.problems import Problem

    probs = [Problem(start=np.array([0.3 + 0.01 * k, 0.2, 0.0, 1.0, 0.0]), goal=0.4) for k in range(3)]
    rand = np.zeros((6, 3))
    choices = [Choice(rand, "fallback", 0), Choice(np.ones((2, 3)), "plan", 5), Choice(rand, "fallback", 0)]

    def drive(fallback: str, found: list[bool]):
        run = SimpleNamespace(
            ctx=SimpleNamespace(exp=ExperimentConfig(fallback=fallback), seed=7), method="random_plan", plan_errors=0
        )
        gen = MethodRun._plan_fallbacks(run, probs, choices, 3, 6)
        try:
            need = next(gen)
        except StopIteration as done:
            return None, done.value
        plans = [
            SimpleNamespace(
                found=f,
                stats=SimpleNamespace(termination="found" if f else "budget"),
                trajectory=SimpleNamespace(actions=np.full((3, 3), k)) if f else None,
            )
            for k, f in enumerate(found)
        ]
        try:
            gen.send(plans)
        except StopIteration as done:
            return need, done.value

    need, out = drive("model_plan", [True, False])
    assert isinstance(need, PlanNeed) and need.mde is None
    assert [r.kind for r in need.requests] == ["plan", "plan"]
    np.testing.assert_array_equal(need.requests[1].start, probs[2].start)
    assert [r.seed for r in need.requests] == [derive_seed(7, "fallback-plan", 3, 6 + j) for j in (0, 2)]
    assert [c.source for c in out] == ["fallback_plan", "plan", "fallback"]
    np.testing.assert_array_equal(out[0].actions, np.zeros((3, 3)))
    assert out[2].actions is rand and [c.source for c in choices] == ["fallback", "plan", "fallback"]  # input untouched
    need, out = drive("random_actions", [])
    assert need is None and out is choices
    with pytest.raises(
        ValueError, match=r"experiment.fallback = 'plans': allowed one of \('random_actions', 'model_plan'\)"
    ):
        ExperimentConfig(fallback="plans").validate()


def test_a_refused_cli_run_leaves_the_hydra_record_and_config_as_they_were(cache, straight_run, tmp_path):
    """Hydra's own record (.hydra/) is written only once a run directory is accepted: a refused rerun (another
    seed into a finished run's folder) exits non-zero and changes no file of the folder."""
    out = _copy_run(straight_run[0], tmp_path / "run")
    (out / ".hydra").mkdir()
    (out / ".hydra" / "config.yaml").write_text("the accepted run's record\n")
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    cmd = [sys.executable, "-m", "active.run", *tiny_overrides(cache), "seed=1", f"hydra.run.dir={out}"]
    done = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode != 0 and "holds results of a different configuration" in done.stderr
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


@pytest.mark.parametrize("kind", ["file", "unwritable"])
def test_a_bad_run_directory_gets_the_projects_message_before_hydra_starts(tmp_path, kind):
    """An existing file, or a folder that cannot be written, named as hydra.run.dir: the project's message naming
    the folder and the field, exit code 2, not Hydra's FileExistsError / PermissionError traceback."""
    if kind == "file":
        target = tmp_path / "a-file"
        target.write_text("x")
    else:
        if os.geteuid() == 0:
            pytest.skip("root writes into a read-only folder; the file case covers the same path")
        parent = tmp_path / "ro"
        parent.mkdir(mode=0o500)
        target = parent / "run"
    cmd = [sys.executable, "-m", "active.run", "experiment=tiny", "wandb.mode=disabled", f"hydra.run.dir={target}"]
    done = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2, done.stderr[-2000:]
    assert f"output directory {target} is not writable" in done.stderr and "hydra.run.dir=" in done.stderr
    assert "Traceback" not in done.stderr


def test_run_folders_carry_the_result_changing_overrides():
    """An ablation or a sweep over any key gets its own folder; seed, method and how a run is carried out do not
    make a level; the default run stays at outputs/quick/all/seed0."""
    from active.run import hydra_run_dir

    assert hydra_run_dir([]) == Path("outputs/quick/all/seed0")
    assert hydra_run_dir(["mde.label_max=0.15", "seed=3", "planner.workers=2", "progress=false"]) == Path(
        "outputs/quick/mde.label_max=0.15/all/seed3"
    )
    assert hydra_run_dir(["experiment=paper", "seeds=[0,1]", "method=random_plan"]) == Path(
        "outputs/paper/random_plan/seeds0-1"
    )
    assert hydra_run_dir(["-m", "seed=0,1"]) is None  # a sweep's folders are Hydra's (sweep.subdir, the same parts)


def test_the_headline_metric_is_the_best_methods_area(straight_run):
    from active.run import headline

    _, made = straight_run
    best = max(r["auc_success"] for r in made["summary"])
    assert headline(made) == best and headline({"summary": []}) is None


def test_derived_files_are_rewritten_from_the_state_and_a_damaged_checkpoint_is_refused(cache, straight_run, tmp_path):
    """The state is the source of truth: a rerun of a finished run rewrites a truncated or edited results.csv from
    it (the report then reads the true rows); a checkpoint whose bytes changed is refused before any compute,
    naming the file, although torch would load it."""
    out = _copy_run(straight_run[0], tmp_path / "run")
    results = out / "random_actions" / "results.csv"
    results.write_bytes(results.read_bytes()[:-20])
    rows = (out / "active_balanced" / "results.csv").read_text().splitlines()
    (out / "active_balanced" / "results.csv").write_text(
        "\n".join(rows[:1] + [rows[1].replace("0.", "9.", 1)] + rows[2:])
    )
    run_experiment(compose_config(tiny_overrides(cache)), out)
    for method in ("active_balanced", "random_actions"):
        assert read_csv(out / method / "results.csv") == read_csv(straight_run[0] / method / "results.csv")
    ckpt = out / "active_balanced" / "mde_iter002.pt"
    raw = bytearray(ckpt.read_bytes())
    raw[len(raw) // 2 : len(raw) // 2 + 64] = bytes(64)
    ckpt.write_bytes(bytes(raw))
    with pytest.raises(RunFileError, match=rf"{ckpt} is damaged"):
        run_experiment(compose_config(tiny_overrides(cache)), out)


def test_a_complete_dynamics_cache_is_not_probed_for_writing(cache, straight_run, tmp_path, monkeypatch):
    """An ensemble caches its members one by one (never a model of its own hash): a complete cache is recognised as
    such, so a read-only one works; an incomplete one must be writable. (A probe counter stands in for the file
    system's refusal, which root does not get.)"""
    import active.preflight as pf
    from dynamics import DynamicsConfig
    from sim.world import WorldConfig

    probed = []
    monkeypatch.setattr(pf, "check_writable", lambda folders, **kw: probed.append(kw.get("field")))
    cfg = compose_config(tiny_overrides(cache))
    pf.check_dynamics(DynamicsConfig.from_dict(cfg["dynamics"]), WorldConfig.from_mapping(cfg["world"]))
    assert probed == []  # the tiny run trained and cached every member
    empty = compose_config(tiny_overrides(tmp_path / "empty-cache"))
    pf.check_dynamics(DynamicsConfig.from_dict(empty["dynamics"]), WorldConfig.from_mapping(empty["world"]))
    assert probed == ["dynamics.cache_root"]
