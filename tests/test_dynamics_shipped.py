"""The shipped default source-world dataset: matches the default config, regenerates bit for bit,
is used only for its own data hash."""

import dataclasses
import logging
import shutil

import numpy as np
import pytest

import dynamics.shipped as shipped
from dynamics import train as train_mod
from dynamics.config import single_models
from dynamics.data import Transitions, generate_transitions
from dynamics.train import cache_paths, load_or_generate_dataset
from tests.doubles.synthetic import synthetic_generator


def _default():
    from active.run import compose_config

    cfg = compose_config([])
    c = train_mod._as_config(cfg["dynamics"])
    return c, cache_paths(c, None, cfg["world"])["data_hash"]


def test_default_config_has_its_shipped_dataset():
    c, dh = _default()
    path = train_mod.find_shipped(dh)
    assert path is not None, (
        f"no shipped dataset for the default config (data hash {dh}): the world, solver or data "
        f"config changed; refresh it with `python -m dynamics.shipped`"
    )
    ds = Transitions.load(path, expected_hash=dh)
    assert ds.meta["world"] == "source" and ds.meta["n_batches"] == c.data.n_batches
    assert len(np.unique(ds.traj)) == (c.data.n_batches + c.data.pour_batches) * c.data.batch_size
    assert ds.meta["pours"]["n_batches"] == c.data.pour_batches  # the focused pours follow the random batches


def test_check_says_whether_the_shipped_files_match(tmp_path, monkeypatch, capsys):
    """``python -m dynamics.shipped --check``: every file the default config needs is there with its own hash
    inside; a file under a needed name made by another configuration is reported stale."""
    c, _ = _default()
    assert shipped.check(c)
    assert capsys.readouterr().out.count("matches the configuration") == 1 + c.model.ensemble
    names = [train_mod.shipped_path(cache_paths(c)["data_hash"]).name] + [
        train_mod.shipped_model_path(cache_paths(m)["model_hash"]).name for m in single_models(c)
    ]
    for name in names:
        shutil.copyfile(train_mod.SHIPPED_DIR / name, tmp_path / name)
    shutil.copyfile(tmp_path / names[1], tmp_path / names[2])  # member 0's checkpoint under member 1's name
    monkeypatch.setattr(train_mod, "SHIPPED_DIR", tmp_path)
    assert not shipped.check(c)
    assert f"shipped {names[2]}: STALE" in capsys.readouterr().out


#: Largest difference allowed between the shipped states and states simulated again on a CPU of another kind
#: (``sim.engine.backend.cpu_fingerprint``). Measured: 0.0 on every value of the 115 rows of batch 0, simulated on an
#: AVX-512 machine against the shipped rows made on an AVX2 one (the simulator runs without fast math and its
#: host side uses libm's scalar functions). The states are float32: 1e-6 is a few units in their last place
#: (theta reaches 2.5 rad), far below one particle's share of the water (1/462 = 0.0022) or any pose change,
#: so a single particle that ends in another region fails it.
OTHER_CPU_ATOL = 1e-6


def _same_states(again, ds, rows, made_on: str | None) -> None:
    """Bit for bit where this CPU is of the kind that made the rows; within :data:`OTHER_CPU_ATOL` elsewhere."""
    from sim.engine.backend import cpu_fingerprint

    here = cpu_fingerprint()
    for k in ("s", "s_next"):
        if made_on == here:
            np.testing.assert_array_equal(getattr(again, k), getattr(ds, k)[rows], err_msg=k)
        else:
            np.testing.assert_allclose(
                getattr(again, k),
                getattr(ds, k)[rows],
                rtol=0.0,
                atol=OTHER_CPU_ATOL,
                err_msg=f"{k}: made on {made_on or 'a CPU not recorded'}, here {here}",
            )


def test_first_shard_regenerates_bit_for_bit():
    """Batch 0 of the shipped dataset, simulated again on this CPU, is identical to the shipped rows: what
    the data sampler decides (actions, trajectories, steps, stuck flags) on any machine; the simulated
    states bit for bit on a CPU with the vector instruction sets of the machine that made the file
    (``sim.engine.backend.cpu_fingerprint``), within :data:`OTHER_CPU_ATOL` on another. (States made with Taichi's
    fast math or numpy's vectorised trigonometry moved by a few particles in half of the trajectories on
    another CPU; the simulator uses neither.)"""
    from sim.engine.backend import cpu_fingerprint

    c, dh = _default()
    ds = Transitions.load(train_mod.find_shipped(dh), expected_hash=dh)
    again = generate_transitions(c.data, "source", n_batches=1, progress=False)
    rows = ds.traj < c.data.batch_size
    assert rows.sum() == len(again)
    for k in ("a", "traj", "step", "stuck"):
        np.testing.assert_array_equal(getattr(again, k), getattr(ds, k)[rows], err_msg=k)
    assert again.meta["cpu"] == cpu_fingerprint()
    _same_states(again, ds, rows, ds.meta.get("cpu"))


def test_first_focused_pour_shard_regenerates_bit_for_bit():
    """The same for the first batch of focused pours (``data.pour_batches``), which follow the random batches.
    They record their own CPU (made on AVX-512, where the random batches were made on AVX2); on another kind of
    CPU the tolerance measured on the random batches applies."""
    c, dh = _default()
    ds = Transitions.load(train_mod.find_shipped(dh), expected_hash=dh)
    again = generate_transitions(c.data, "source", n_batches=1, progress=False, pours=True)
    first = c.data.n_batches * c.data.batch_size
    rows = (ds.traj >= first) & (ds.traj < first + c.data.batch_size)
    assert rows.sum() == len(again) > 0
    for k in ("a", "traj", "step", "stuck"):
        np.testing.assert_array_equal(getattr(again, k), getattr(ds, k)[rows], err_msg=k)
    _same_states(again, ds, rows, ds.meta["pours"].get("cpu"))  # the focused pours may come from another CPU


def _ship(monkeypatch, tmp_path, src, target):
    """Make ``tmp_path/shipped`` the package's shipped folder and copy ``src`` to ``target()`` in it."""
    monkeypatch.setattr(train_mod, "SHIPPED_DIR", tmp_path / "shipped")
    (tmp_path / "shipped").mkdir()
    shutil.copyfile(src, target())


def test_shipped_file_is_used_only_for_its_own_hash(tmp_path, monkeypatch, caplog):
    c = train_mod._as_config({"progress": False, "data": {"n_batches": 1, "batch_size": 4, "max_actions": 4}})
    made = load_or_generate_dataset(c, tmp_path / "a", generator=lambda cfg, **kw: synthetic_generator(cfg))
    dh = cache_paths(c, tmp_path / "a")["data_hash"]
    _ship(monkeypatch, tmp_path, cache_paths(c, tmp_path / "a")["dataset"], lambda: train_mod.shipped_path(dh))

    def no_simulation(*a, **k):
        raise AssertionError("the simulator ran although a matching shipped dataset exists")

    monkeypatch.setattr("dynamics.data.generate_source_dataset", no_simulation)
    with caplog.at_level(logging.INFO, logger="dynamics.train"):
        got = load_or_generate_dataset(c, tmp_path / "b")
    assert "using the shipped" in caplog.text
    np.testing.assert_array_equal(got.s_next, made.s_next)
    # another data config: the shipped file is named as made by another configuration, and not used
    other = train_mod._as_config(
        {"progress": False, "data": {"n_batches": 1, "batch_size": 4, "max_actions": 4, "seed": 5}}
    )
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="dynamics.train"), pytest.raises(AssertionError, match="simulator ran"):
        load_or_generate_dataset(other, tmp_path / "c")
    assert "another configuration" in caplog.text and train_mod.shipped_path(dh).name in caplog.text


def _default_members():
    from active.run import compose_config

    cfg = compose_config([])
    c = train_mod._as_config(cfg["dynamics"])
    singles = single_models(c)
    return cfg, [(m, cache_paths(m, None, cfg["world"])["model_hash"]) for m in singles]


def test_default_config_has_its_shipped_models():
    """Every member of the default model ships, trained on the shipped dataset with the default settings."""
    from dynamics import LearnedDynamics

    cfg, members = _default_members()
    dh = cache_paths(cfg["dynamics"], None, cfg["world"])["data_hash"]
    for m, mh in members:
        path = train_mod.shipped_model_path(mh)
        assert path.is_file(), (
            f"no shipped model for member seed {m.train.seed} of the default config (model hash "
            f"{mh}): refresh them with `python -m dynamics.shipped`"
        )
        model = LearnedDynamics.load(path, expected_hash=mh)
        assert model.info["data_hash"] == dh and model.info["config"] == m.to_dict()


def test_shipped_model_is_used_only_for_its_own_hash(tmp_path, monkeypatch, caplog):
    from dynamics.train import load_or_train

    gen = lambda cfg, **kw: synthetic_generator(cfg)  # noqa: E731
    c = train_mod._as_config(
        {
            "progress": False,
            "data": {"n_batches": 1, "batch_size": 4, "max_actions": 4},
            "model": {"hidden": [8], "ensemble": 1},
            "train": {"max_epochs": 2, "patience": 2},
        }
    )
    made = load_or_train(c, tmp_path / "a", generator=gen)
    mh = cache_paths(c, tmp_path / "a")["model_hash"]
    _ship(monkeypatch, tmp_path, cache_paths(c, tmp_path / "a")["checkpoint"], lambda: train_mod.shipped_model_path(mh))

    def no_training(*a, **k):
        raise AssertionError("trained although a matching shipped model exists")

    monkeypatch.setattr(train_mod, "fit", no_training)
    monkeypatch.setattr("dynamics.data.generate_source_dataset", no_training)
    with caplog.at_level(logging.INFO, logger="dynamics.train"):
        got = load_or_train(c, tmp_path / "b")
    assert "using the shipped dynamics model" in caplog.text
    assert (tmp_path / "b" / f"model-{mh}" / "metrics.json").is_file()  # the cache entry is complete
    s, a = np.array([[0.3, 0.2, 0.0, 1.0, 0.0]]), np.array([[1, 1.4, 0.5]])
    np.testing.assert_array_equal(got.predict_np(s, a), made.predict_np(s, a))
    # another training setting: another model hash, the shipped model is not used
    other = c.replace(train=dataclasses.replace(c.train, seed=5))
    with pytest.raises(AssertionError, match="trained although"):
        load_or_train(other, tmp_path / "c")
    with pytest.raises(AssertionError, match="trained although"):  # nor when asked not to
        load_or_train(c, tmp_path / "d", use_shipped=False)
    # a damaged shipped file is not copied into the cache: the model is trained instead
    train_mod.shipped_model_path(mh).write_bytes(b"not a checkpoint")
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="dynamics.train"), pytest.raises(AssertionError, match="trained"):
        load_or_train(c, tmp_path / "e")
    assert "cannot be used" in caplog.text and not cache_paths(c, tmp_path / "e")["checkpoint"].exists()


@pytest.mark.slow
def test_a_shipped_member_retrains_to_the_same_model(tmp_path):
    """Member 0 trained again on the shipped data predicts what the shipped checkpoint predicts.

    Bit for bit on the CPU that shipped it; another CPU's float rounding may differ, hence a tolerance
    on predictions (pour outcomes within 0.005) rather than equal weights."""
    from dynamics import LearnedDynamics
    from dynamics.train import load_or_train

    cfg, members = _default_members()
    m, mh = members[0]
    shipped_model = LearnedDynamics.load(train_mod.shipped_model_path(mh), expected_hash=mh)
    again = load_or_train(m, tmp_path, world_cfg=cfg["world"], use_shipped=False)
    ds = Transitions.load(train_mod.find_shipped(shipped_model.info["data_hash"]))
    idx = np.random.default_rng(0).choice(len(ds), 2000, replace=False)
    diff = np.abs(again.predict_np(ds.s[idx], ds.a[idx]) - shipped_model.predict_np(ds.s[idx], ds.a[idx]))
    assert diff.max() < 0.005, diff.max(0)
