"""The shipped default source-world dataset: matches the default config, regenerates bit for bit,
is used only for its own data hash."""

import logging
import shutil

import numpy as np
import pytest

import dynamics.shipped as shipped
from dynamics import train as train_mod
from dynamics.config import DynamicsConfig
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
    path = shipped.find_shipped(dh)
    assert path is not None, (f"no shipped dataset for the default config (data hash {dh}): the world, solver or data "
                              f"config changed; refresh it with `python -m dynamics.shipped`")
    ds = Transitions.load(path, expected_hash=dh)
    assert ds.meta["world"] == "source" and ds.meta["n_batches"] == c.data.n_batches
    assert len(np.unique(ds.traj)) == c.data.n_batches * c.data.batch_size


def test_first_shard_regenerates_bit_for_bit():
    """Batch 0 of the shipped dataset, simulated again on this CPU, is identical to the shipped rows."""
    c, dh = _default()
    ds = Transitions.load(shipped.find_shipped(dh), expected_hash=dh)
    again = generate_transitions(c.data, "source", n_batches=1, progress=False)
    rows = ds.traj < c.data.batch_size
    assert rows.sum() == len(again)
    for k in ("s", "a", "s_next", "traj", "step", "stuck"):
        np.testing.assert_array_equal(getattr(again, k), getattr(ds, k)[rows], err_msg=k)


def test_shipped_file_is_used_only_for_its_own_hash(tmp_path, monkeypatch, caplog):
    c = train_mod._as_config({"progress": False, "data": {"n_batches": 1, "batch_size": 4, "max_actions": 4}})
    made = load_or_generate_dataset(c, tmp_path / "a", generator=lambda cfg, **kw: synthetic_generator(cfg))
    dh = cache_paths(c, tmp_path / "a")["data_hash"]
    monkeypatch.setattr(shipped, "SHIPPED_DIR", tmp_path / "shipped")
    (tmp_path / "shipped").mkdir()
    shutil.copyfile(cache_paths(c, tmp_path / "a")["dataset"], shipped.shipped_path(dh))

    def no_simulation(*a, **k):
        raise AssertionError("the simulator ran although a matching shipped dataset exists")

    monkeypatch.setattr("dynamics.data.generate_source_dataset", no_simulation)
    with caplog.at_level(logging.INFO, logger="dynamics.shipped"):
        got = load_or_generate_dataset(c, tmp_path / "b")
    assert "using the shipped" in caplog.text
    np.testing.assert_array_equal(got.s_next, made.s_next)
    # another data config: the shipped file is named as made by another configuration, and not used
    other = train_mod._as_config({"progress": False, "data": {"n_batches": 1, "batch_size": 4, "max_actions": 4,
                                                                     "seed": 5}})
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="dynamics.shipped"), pytest.raises(AssertionError, match="simulator ran"):
        load_or_generate_dataset(other, tmp_path / "c")
    assert "another configuration" in caplog.text and shipped.shipped_path(dh).name in caplog.text
