"""Run integrity without running an experiment: the atomic writer, the run lock (two real processes),
pre-compute checks, what a run directory may reuse, clear errors for damaged files, leftovers.

The end-to-end versions (the real CLI, the tiny experiment) are in tests/test_active_run.py.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import signal
import socket
import stat
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import safeio
from active import runlock
from active.calibration import CALIBRATION_FORMAT, load_calibration, save_calibration
from active.identity import RUN_FORMAT, RUN_FORMAT_VERSION, config_differences, config_digest
from active.io import RunFileError, load_checked, load_torch, read_csv, save_checked
from active.preflight import check_geometry, check_seed, check_writable, max_dx
from active.rundir import check_run_directory, load_mde_checkpoint
from active.runlock import RunDirectoryError, RunLock, RunLockedError, read_owner

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def umask027():
    old = os.umask(0o027)
    yield 0o640
    os.umask(old)


def _mode(p: Path) -> int:
    return stat.S_IMODE(p.stat().st_mode)


# ------------------------------------------------------------------ the one atomic writer
def test_writer_respects_umask_fsyncs_and_leaves_no_temporary_file(tmp_path, umask027, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    synced = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd)))
    safeio.write_text(tmp_path / "a" / "t.txt", "hello")
    safeio.write_json(tmp_path / "a" / "j.json", {"x": torch.tensor([1.0, 2.0]), "t": (1, 2), "p": tmp_path})
    safeio.save_torch(tmp_path / "a" / "m.pt", {"w": torch.arange(3)})
    fig = Figure()
    fig.add_subplot().plot([0, 1])
    safeio.save_figure(fig, tmp_path / "a" / "f.png")
    files = sorted((tmp_path / "a").iterdir())
    assert [p.name for p in files] == ["f.png", "j.json", "m.pt", "t.txt"]  # no temporary file left
    assert {_mode(p) for p in files} == {umask027}  # group-readable, not mkstemp's 0600
    assert len(synced) >= 8  # every file and its directory entry
    assert (tmp_path / "a" / "t.txt").read_text() == "hello"
    assert json.loads((tmp_path / "a" / "j.json").read_text()) == {"x": [1.0, 2.0], "t": [1, 2], "p": str(tmp_path)}
    assert torch.equal(torch.load(tmp_path / "a" / "m.pt")["w"], torch.arange(3))
    assert (tmp_path / "a" / "f.png").read_bytes()[:4] == b"\x89PNG"


def test_failed_write_keeps_the_old_file(tmp_path):
    path = safeio.write_text(tmp_path / "r.csv", "old")

    def half(f):
        f.write(b"ne")
        raise KeyboardInterrupt  # e.g. a signal in the middle of the write

    with pytest.raises(KeyboardInterrupt):
        safeio.atomic_write(path, half)
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["r.csv"]


def test_adopt_and_orphan_removal(tmp_path, umask027):
    foreign = tmp_path / "mde.pt"
    foreign.write_bytes(b"x")
    os.chmod(foreign, 0o600)  # what a mkstemp-based writer leaves
    safeio.adopt(foreign)
    assert _mode(foreign) == umask027
    for name in (".results.csv.123.abcd.tmp", ".mde_iter001.pt.k2j3.tmp", "keep.tmp", ".keep", "data.pt"):
        (tmp_path / name).write_bytes(b"")
    removed = safeio.remove_orphans(tmp_path)
    assert sorted(p.name for p in removed) == [".mde_iter001.pt.k2j3.tmp", ".results.csv.123.abcd.tmp"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [".keep", "data.pt", "keep.tmp", "mde.pt"]


# ------------------------------------------------------------------ the run lock
HOLDER = (
    "import sys, time\nfrom active.runlock import RunLock\nlock = RunLock(sys.argv[1])\nlock.acquire()\n"
    "print('locked', flush=True)\ntime.sleep(120)\n"
)


def _start_holder(folder: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], cwd=REPO, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "locked"
    return proc


def test_lock_refuses_a_live_owner_and_takes_over_a_dead_one(tmp_path, caplog):
    """Two real processes: the second is refused while the first lives; after SIGKILL it takes over."""
    holder = _start_holder(tmp_path)
    try:
        owner = read_owner(tmp_path)
        assert owner["pid"] == holder.pid and owner["host"] == socket.gethostname()
        with pytest.raises(
            RunLockedError,
            match=rf"in use by another run: pid {holder.pid} on host "
            rf"{socket.gethostname()}.*Wait for it to finish",
        ):
            RunLock(tmp_path).acquire()
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert read_owner(tmp_path)["pid"] == holder.pid  # the dead owner's record is still there
    with caplog.at_level(logging.WARNING, logger="active.runlock"):
        with RunLock(tmp_path) as lock:
            assert lock.previous["pid"] == holder.pid
            assert read_owner(tmp_path)["pid"] == os.getpid()
            with pytest.raises(RunLockedError, match="already in use by a run of this process"):
                RunLock(tmp_path).acquire()
    assert f"taking over {tmp_path / 'run.lock'} from pid {holder.pid}" in caplog.text
    assert read_owner(tmp_path) is None  # released: emptied, not deleted


def test_lock_without_file_system_locks_uses_the_pid_record(tmp_path, monkeypatch):
    real = runlock.fcntl.lockf

    def no_locks(fd, op, *a):
        if op & runlock.fcntl.LOCK_EX:
            raise OSError(errno.ENOLCK, "No locks available")
        return real(fd, op, *a)

    monkeypatch.setattr(runlock.fcntl, "lockf", no_locks)
    path = tmp_path / "run.lock"
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        path.write_text(json.dumps({"pid": sleeper.pid, "host": socket.gethostname()}))
        with pytest.raises(RunLockedError, match=rf"pid {sleeper.pid}.*if that run has ended, delete"):
            RunLock(tmp_path).acquire()
    finally:
        sleeper.kill()
        sleeper.wait()
    with RunLock(tmp_path) as lock:  # the same pid, now dead: taken over
        assert lock.previous["pid"] == sleeper.pid
    path.write_text(json.dumps({"pid": 1, "host": "another-node"}))  # cannot be checked from here: refused
    with pytest.raises(RunLockedError, match="on host another-node"):
        RunLock(tmp_path).acquire()


# ------------------------------------------------------------------ checks before compute
@pytest.mark.parametrize("bad", [-1, 2**32, True, "3", 1.5, None])
def test_seed_check_names_the_field_and_range(bad):
    with pytest.raises(ValueError, match=r"^seed = .*: allowed an integer in \[0, 4294967295\]$"):
        check_seed(bad)
    assert check_seed(0) == 0 and check_seed(2**32 - 1) == 2**32 - 1


def test_resolution_against_the_geometry():
    from sim.world import WorldConfig

    world = WorldConfig.load()
    check_geometry(world)
    assert max_dx(world)[0] == pytest.approx(0.01)  # the cup walls (20 mm) must be >= 2 cells
    check_geometry(
        WorldConfig.load(
            Path(REPO / "configs" / "world" / "default.yaml"),
            sim={**world.sim, "dx": 0.005, "dt": 2e-4, "wall_cells": 6},
        )
    )  # world=fine
    coarse = WorldConfig.load(sim={**world.sim, "dx": 0.05})  # the probe's 50 mm cells: cup 70 mm wide
    with pytest.raises(
        ValueError,
        match=r"world.sim.dx = 0.05: too coarse .*cup walls.*tank walls.*"
        r"Allowed: 0 < dx <= 0.01 m",
    ):
        check_geometry(coarse)
    near = WorldConfig.load(problems={**world.problems, "start_x": [0.25, 0.5]})
    with pytest.raises(ValueError, match=r"world.problems.start_x = \[0.25, 0.5\].*overlaps the target body"):
        check_geometry(near)


def test_unwritable_output_is_found_before_compute(tmp_path):
    (tmp_path / "active_balanced").write_text("a file where a method directory belongs")
    with pytest.raises(RunDirectoryError, match=r"active_balanced is not writable .*a file is in the way"):
        check_writable([tmp_path, tmp_path / "active_balanced"])
    with pytest.raises(ValueError, match=r"dynamics cache .* is not writable.*dynamics.cache_root="):
        check_writable([tmp_path / "active_balanced" / "cache"], what="dynamics cache", field="dynamics.cache_root")
    if os.geteuid() != 0:  # root writes anywhere
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o555)
        with pytest.raises(RunDirectoryError, match="ro is not writable"):
            check_writable([ro])
    assert not list(tmp_path.glob(".write-probe*"))


# ------------------------------------------------------------------ what a directory may reuse
def _cfg(**over) -> dict:
    cfg = {
        "seed": 0,
        "method": "all",
        "progress": False,
        "wandb": {"mode": "disabled"},
        "experiment": {"name": "tiny", "iterations": 2, "methods": ["a"]},
        "dynamics": {"cache_root": "/old/cache", "progress": False, "data": {"seed": 0}},
        "mde": {"nu": 2.5},
    }
    for k, v in over.items():
        cfg[k] = {**cfg[k], **v} if isinstance(v, dict) else v
    return cfg


def test_digests_ignore_the_cache_location():
    a, moved = _cfg(), _cfg(dynamics={"cache_root": "/new/cache", "progress": True})
    assert config_digest(a) == config_digest(moved)
    assert config_digest(a) == config_digest(_cfg(experiment={"iterations": 20}))
    assert config_digest(a) != config_digest(_cfg(seed=1))
    assert config_differences(a, _cfg(seed=1, mde={"nu": 1.5})) == ["mde.nu: 2.5 -> 1.5", "seed: 0 -> 1"]
    assert config_differences(a, moved) == []


def _write_state(folder: Path, digest: str, completed: int = 1) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    save_checked(
        folder / "state.pt",
        {
            "format": RUN_FORMAT,
            "version": RUN_FORMAT_VERSION,
            "digest": digest,
            "completed": completed,
            "mde_path": None,
        },
    )
    for name in ("results.csv", "categories.csv", "dataset.pt"):
        (folder / name).write_text("x")
    return folder / "state.pt"


def test_directory_of_another_configuration_is_refused_with_the_differences(tmp_path):
    old = _cfg()
    safeio.write_json(tmp_path / "config.json", old)
    _write_state(tmp_path / "a", config_digest(old), completed=2)
    before = (tmp_path / "config.json").read_bytes()
    with pytest.raises(
        RunDirectoryError,
        match=r"holds results of a different configuration \(a \(2 iterations\)\)"
        r": it differs in seed: 0 -> 1\. Nothing was changed",
    ):
        check_run_directory(tmp_path, _cfg(seed=1))
    assert (tmp_path / "config.json").read_bytes() == before
    assert check_run_directory(tmp_path, _cfg(dynamics={"cache_root": "/moved"}))  # resumable


def test_fewer_iterations_than_a_directory_holds_are_refused(tmp_path):
    """experiment.iterations lowered on a finished run: refused naming the field, nothing rewritten."""
    cfg = _cfg()  # 2 iterations
    safeio.write_json(tmp_path / "config.json", cfg)
    _write_state(tmp_path / "a", config_digest(cfg), completed=2)
    assert check_run_directory(tmp_path, cfg)
    before = (tmp_path / "config.json").read_bytes()
    with pytest.raises(
        RunDirectoryError,
        match=r"experiment.iterations = 1: .* holds more completed iterations "
        r"\(a \(2 iterations\)\)\. Nothing was changed",
    ):
        check_run_directory(tmp_path, _cfg(experiment={"iterations": 1}))
    assert (tmp_path / "config.json").read_bytes() == before


def test_damaged_state_names_the_file_and_what_survives(tmp_path):
    path = _write_state(tmp_path / "a", "x")
    path.write_bytes(path.read_bytes()[:50])
    with pytest.raises(RunFileError) as e:
        check_run_directory(tmp_path, _cfg())
    msg = str(e.value)
    assert str(path) in msg and "is unreadable (truncated or damaged" in msg
    assert "categories.csv, dataset.pt, results.csv beside it are intact and kept" in msg
    assert "delete it and run the same command again to redo this method from iteration 1" in msg


def _set(value: float) -> dict:
    return {"X": torch.full((2, 8), value), "y": torch.full((2,), value)}


def test_calibration_set_is_reused_only_for_its_own_configuration(tmp_path, caplog):
    path = tmp_path / "calibration_set.pt"
    seed0, seed1 = _cfg(), _cfg(seed=1)
    assert load_calibration(path, seed0) is None  # none yet
    save_calibration(path, _set(0.0), seed0)
    assert load_calibration(path, seed0)["y"][0] == 0.0  # reused by its own configuration
    with caplog.at_level(logging.WARNING):  # a seed-0 set left by a run killed before its first iteration
        assert load_calibration(path, seed1) is None
    assert "made by another configuration or run format (seed: 0 -> 1); rebuilding it" in caplog.text
    saved = load_checked(path)
    assert saved["format"] == CALIBRATION_FORMAT and saved["digest"] == config_digest(seed0)
    assert saved["version"] == RUN_FORMAT_VERSION
    # another run format version: rebuilt, never reused
    save_checked(path, {**saved, "version": RUN_FORMAT_VERSION - 1})
    assert load_calibration(path, seed0) is None
    save_checked(path, [1, 2])  # checksummed, but not a set
    with pytest.raises(RunFileError, match="is not a calibration set of this runner"):
        load_calibration(path, seed1)
    safeio.save_torch(path, {"X": torch.zeros(2, 8), "y": torch.full((2,), 5.0)})  # no checksum: another format
    with pytest.raises(RunFileError, match="is not a checksummed file of this code"):
        load_calibration(path, seed1)


def test_damage_inside_a_tensor_is_refused_naming_the_file(tmp_path):
    """torch does not check its zip's CRC-32: 8 bytes changed inside a tensor load silently from a plain file. A
    checked file (state, calibration set) refuses them, naming the file and the fix."""
    path = tmp_path / "calibration_set.pt"
    save_calibration(path, {"X": torch.arange(4096.0).reshape(512, 8), "y": torch.zeros(512)}, _cfg())
    raw = bytearray(path.read_bytes())
    at = raw.find(torch.arange(4096.0)[1000:1002].numpy().tobytes())  # inside X's storage
    assert at > 0
    raw[at : at + 8] = b"\x00" * 8
    path.write_bytes(bytes(raw))
    with pytest.raises(RunFileError, match=rf"{path} is damaged .*delete it and run the same command again"):
        load_calibration(path, _cfg())


@pytest.mark.parametrize(
    "damage, why",
    [
        (lambda b: b[: len(b) - 7], "fewer fields than its header"),
        (lambda b: b + b"1,2,3,4,5,6,7,8,9,10,11,12\n", "more fields than its header"),
        (lambda b: b.replace(b"method", b"m\xffethod", 1), "is not a readable CSV"),
    ],
)
def test_a_damaged_csv_is_refused_naming_the_file_and_line(tmp_path, damage, why):
    path = tmp_path / "results.csv"
    path.write_bytes(b"method,seed,iteration\nrandom_plan,0,1\nrandom_plan,0,2\n")
    assert len(read_csv(path)) == 2
    path.write_bytes(damage(path.read_bytes()))
    with pytest.raises(RunFileError, match=rf"{path}.*{why}"):
        read_csv(path)


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_damaged_calibration_set_names_the_file_and_the_fix(tmp_path, damage):
    path = tmp_path / "calibration_set.pt"
    save_calibration(path, _set(0.0), _cfg())
    path.write_bytes(path.read_bytes()[:200] if damage == "truncate" else b"\x80\x02garbage")
    with pytest.raises(
        RunFileError,
        match=rf"{path} is unreadable .*delete it and run the same command again: it "
        r"is rebuilt from the configuration",
    ) as e:
        load_calibration(path, _cfg())
    assert "weights_only" not in str(e.value)


@pytest.fixture(scope="module")
def fitted_mde(tmp_path_factory):
    from mde import GPMDE

    g = torch.Generator().manual_seed(0)
    X = torch.rand(12, 3, generator=g, dtype=torch.float64)
    y = 0.1 + 0.05 * X[:, 0]
    mde = GPMDE(num_threads=1, max_iters=1, heteroscedastic=False).fit(X, y)
    path = mde.save(tmp_path_factory.mktemp("mde") / "mde_iter001.pt")
    return mde, path, X


@pytest.mark.parametrize(
    "damage,reason", [("truncate", "truncated or damaged"), ("garbage", "not a torch file written by this code")]
)
def test_damaged_mde_checkpoint_names_the_file(tmp_path, fitted_mde, damage, reason):
    from mde import GPMDE

    mde, good, X = fitted_mde
    path = tmp_path / "mde_iter002.pt"
    path.write_bytes(good.read_bytes()[:300] if damage == "truncate" else b"garbage" * 40)
    with pytest.raises(RunFileError, match=rf"MDE checkpoint {path} is unreadable \({reason}") as e:
        load_mde_checkpoint(GPMDE, path, mde, X, tmp_path / "state.pt")
    assert "weights_only" not in str(e.value) and "delete" in str(e.value)


def test_mde_checkpoint_must_belong_to_the_state(fitted_mde, tmp_path):
    from mde import GPMDE

    mde, path, X = fitted_mde
    assert load_mde_checkpoint(GPMDE, path, mde, X, tmp_path / "state.pt").n_train == 12
    with pytest.raises(RunFileError, match="another MDE configuration"):
        load_mde_checkpoint(GPMDE, path, GPMDE(nu=1.5), X, tmp_path / "state.pt")
    with pytest.raises(RunFileError, match="fitted on data that is not this method's saved data"):
        load_mde_checkpoint(GPMDE, path, mde, X + 1, tmp_path / "state.pt")


def test_load_torch_names_the_file(tmp_path):
    (tmp_path / "state.pt").write_bytes(b"")
    with pytest.raises(RunFileError, match=rf"{tmp_path / 'state.pt'} is unreadable.*; restore it"):
        load_torch(tmp_path / "state.pt", fix="restore it")
    with pytest.raises(RunFileError, match="does not exist; restore it"):
        load_torch(tmp_path / "nothing.pt", fix="restore it")


# ------------------------------------------------------------------ dynamics cache leftovers
def test_dynamics_cache_finishes_after_a_kill_and_removes_orphans(tmp_path, monkeypatch):
    """Kills after the dataset / checkpoint was saved left parts/, no config.yaml or metrics.json,
    and temporary files: the next call finishes the folders without regenerating or retraining."""
    import dynamics.train as train_mod
    from dynamics import cache_paths, load_or_train
    from tests.doubles.synthetic import synthetic_generator

    calls = []

    def gen(cfg, shard_dir=None, progress=False, world_cfg=None):
        calls.append("gen")
        return synthetic_generator(cfg)

    real_fit = train_mod.fit

    def counting_fit(*a, **k):
        calls.append("fit")
        return real_fit(*a, **k)

    cfg = {
        "progress": False,
        "data": {"n_batches": 1, "batch_size": 8, "max_actions": 4, "pour_batches": 0},
        "model": {"hidden": [8], "ensemble": 1},
        "train": {"max_epochs": 2, "patience": 2},
    }
    monkeypatch.setattr("dynamics.data.generate_source_dataset", gen)
    monkeypatch.setattr(train_mod, "fit", counting_fit)
    load_or_train(cfg, tmp_path)
    p = cache_paths(cfg, tmp_path)
    data, model = p["dataset"].parent, p["checkpoint"].parent
    (data / "config.yaml").unlink()
    (data / "parts").mkdir()
    (data / "parts" / "batch0000.pt").write_bytes(b"shard")
    (data / "parts" / ".batch0001.pt.77.ab.tmp").write_bytes(b"half")
    (data / ".dataset.pt.77.cd.tmp").write_bytes(b"half")
    (model / "metrics.json").unlink()
    (model / ".model.pt.78.ef.tmp").write_bytes(b"half")
    load_or_train(cfg, tmp_path)
    assert calls == ["gen", "fit"]  # neither regenerated nor retrained
    assert sorted(p.name for p in data.iterdir()) == [".lock", "config.yaml", "dataset.pt"]
    assert sorted(p.name for p in model.iterdir()) == [".lock", "config.yaml", "metrics.json", "model.pt"]
    assert json.loads((model / "metrics.json").read_text())["epochs_run"] >= 1


def test_shard_identity_covers_the_generator_and_the_world():
    from dynamics.config import DataConfig
    from dynamics.data import shard_identity
    from sim.world import WorldConfig

    world = WorldConfig.load()
    a = shard_identity(DataConfig(), world)
    assert a == shard_identity(DataConfig(n_batches=99), world)  # a batch does not depend on the count
    assert a != shard_identity(DataConfig(p_pour=0.5), world)
    assert a != shard_identity(DataConfig(), WorldConfig.load(skills={**world.skills, "settle": 0.3}))
