"""Training: recovers a known transition function, is reproducible, and the cache behaves."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import dynamics.train as train_mod
from dynamics import (
    DynamicsError,
    ModelConfig,
    TrainConfig,
    Transitions,
    cache_paths,
    error_table,
    fit,
    load_or_generate_dataset,
    load_or_train,
)
from dynamics.train import split_by_trajectory
from tests.doubles.synthetic import synthetic_generator, synthetic_transitions

SMALL = ModelConfig(hidden=(48, 48))


def test_learns_known_transition_function():
    ds = synthetic_transitions(300, n_steps=5, seed=0)
    model = fit(ds, SMALL, TrainConfig(max_epochs=80, patience=20, batch_size=64))
    val = model.info["training"]["val_errors"]
    test = error_table(model, synthetic_transitions(150, n_steps=5, seed=1))
    for table in (val, test):
        assert table["move"]["mae_x"] < 1e-3 and table["move"]["mae_theta"] < 1e-3
        assert table["move"]["mae_y"] < 0.01  # the blocked region's edge is a discontinuity
        assert table["pour"]["mae_x"] < 1e-3 and table["pour"]["mae_y"] < 1e-3
        assert table["pour"]["mae_v_ctrl"] < 0.04 and table["pour"]["mae_v_tgt"] < 0.03
    # and far better than predicting "nothing changes" for pours
    t = synthetic_transitions(150, n_steps=5, seed=1)
    pour = t.skill() == 1
    still = np.abs(t.s[pour, 3] - t.s_next[pour, 3]).mean()
    assert test["pour"]["mae_v_ctrl"] < 0.25 * still


@pytest.mark.parametrize("loss", ["distance", "scaled_mse"])
def test_seeded_training_is_deterministic(loss):
    ds = synthetic_transitions(60, n_steps=3, seed=3)
    cfg = TrainConfig(max_epochs=8, patience=8, batch_size=32, seed=5, loss=loss)
    a, b = fit(ds, SMALL, cfg), fit(ds, SMALL, cfg)
    sa, sb = a.state_dict(), b.state_dict()
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    hist = a.info["training"]["history"]
    assert hist[-1][0] < hist[0][0]  # the training loss went down
    c = fit(ds, SMALL, TrainConfig(max_epochs=8, patience=8, batch_size=32, seed=6, loss=loss))
    assert not all(torch.equal(sa[k], c.state_dict()[k]) for k in sa)


def test_cosine_schedule_anneals_the_step_size_to_zero():
    ds = synthetic_transitions(60, n_steps=3, seed=3)
    runs = {
        s: fit(ds, SMALL, TrainConfig(max_epochs=6, patience=6, batch_size=32, seed=5, lr=2e-3, lr_schedule=s))
        for s in ("constant", "cosine")
    }
    assert runs["constant"].info["training"]["final_lr"] == pytest.approx(2e-3)
    assert runs["cosine"].info["training"]["final_lr"] == pytest.approx(0.0, abs=1e-12)
    a, b = (runs[s].state_dict() for s in ("constant", "cosine"))
    assert not all(torch.equal(a[k], b[k]) for k in a)  # the schedule acts on the weights


def test_split_keeps_trajectories_whole():
    traj = np.repeat(np.arange(20), 3)
    tr, va = split_by_trajectory(traj, 0.25, seed=0)
    assert len(tr) + len(va) == 60 and len(va) == 15
    assert not set(traj[tr]) & set(traj[va])
    tr, va = split_by_trajectory(np.zeros(4, int), 0.25, seed=0)  # one trajectory: no validation split
    assert len(tr) == 4 and len(va) == 0


@pytest.fixture
def counted(monkeypatch):
    """Synthetic generator and fit, both counting their calls."""
    calls = {"gen": 0, "fit": 0, "world_cfg": None}

    def gen(cfg, shard_dir=None, progress=False, world_cfg=None):
        calls["gen"] += 1
        calls["world_cfg"] = world_cfg
        return synthetic_generator(cfg)

    real_fit = train_mod.fit

    def counting_fit(*a, **k):
        calls["fit"] += 1
        return real_fit(*a, **k)

    monkeypatch.setattr("dynamics.data.generate_source_dataset", gen)
    monkeypatch.setattr(train_mod, "fit", counting_fit)
    return calls


def tiny(**over) -> dict:
    d = {
        "progress": False,
        "data": {"n_batches": 1, "batch_size": 16, "max_actions": 4, "pour_batches": 0},
        "model": {"hidden": [16], "ensemble": 1},
        "train": {"max_epochs": 3, "patience": 3},
    }
    for k, v in over.items():
        d[k] = {**d.get(k, {}), **v}
    return d


def test_cache_reuse_and_invalidation(tmp_path, counted):
    m1 = load_or_train(tiny(), tmp_path)
    assert (counted["gen"], counted["fit"], counted["world_cfg"]) == (1, 1, None)
    p = cache_paths(tiny(), tmp_path)
    assert p["dataset"].is_file() and p["checkpoint"].is_file()
    assert (p["checkpoint"].parent / "metrics.json").is_file() and (p["dataset"].parent / "config.yaml").is_file()
    m2 = load_or_train(tiny(), tmp_path)  # same config: nothing regenerated or retrained
    assert (counted["gen"], counted["fit"], counted["world_cfg"]) == (1, 1, None)
    s, a = np.array([[0.4, 0.2, 0, 1, 0]]), np.array([[1, 1.0, 0.5]])
    assert np.array_equal(m1.predict_np(s, a), m2.predict_np(s, a))
    load_or_train(tiny(train={"lr": 1e-3}), tmp_path)  # training field: retrain on the cached data
    assert (counted["gen"], counted["fit"]) == (1, 2)
    load_or_train(tiny(data={"seed": 1}), tmp_path)  # data field: regenerate and retrain
    assert (counted["gen"], counted["fit"]) == (2, 3)
    load_or_train(tiny(eval={"seed": 9}), tmp_path)  # evaluation field: neither
    assert (counted["gen"], counted["fit"]) == (2, 3)
    # the config dict as the main job passes it (OmegaConf) works too
    from omegaconf import OmegaConf

    load_or_train(OmegaConf.create(tiny()), tmp_path)
    assert (counted["gen"], counted["fit"]) == (2, 3)
    # the experiment's world config reaches the generator and the hash
    from sim.world import WorldConfig

    slow = WorldConfig.load(skills={**WorldConfig.load().skills, "settle": 0.3})
    load_or_train(tiny(), tmp_path, world_cfg=slow)
    assert (counted["gen"], counted["fit"]) == (3, 4) and counted["world_cfg"] is slow
    assert m1.info["model_hash"] == p["model_hash"] and m1.info["config"]["data"]["n_batches"] == 1


def test_an_ensemble_is_the_mean_of_members_cached_as_single_models(tmp_path, counted):
    from dynamics import DynamicsEnsemble, DynamicsError
    from dynamics.config import DynamicsConfig, ensemble_member

    ens = load_or_train(tiny(model={"ensemble": 2}, train={"seed": 1}), tmp_path)
    assert isinstance(ens, DynamicsEnsemble) and (counted["gen"], counted["fit"]) == (1, 2)
    # member k of seed s is the single model of seed s * n + k: cached, so loading it trains nothing
    members = [load_or_train(tiny(train={"seed": s}), tmp_path) for s in (2, 3)]
    assert (counted["gen"], counted["fit"]) == (1, 2)
    assert ens.info["members"] == [m.info["model_hash"] for m in members]
    assert ens.info["model_hash"] == cache_paths(tiny(model={"ensemble": 2}, train={"seed": 1}), tmp_path)["model_hash"]
    s = np.array([[0.4, 0.2, 0, 1, 0], [0.3, 0.25, 0, 0.6, 0.3]])
    a = np.array([[1, 1.4, 0.5], [0, 0.35, 0.2]])
    mean = (members[0].predict_np(s, a) + members[1].predict_np(s, a)) / 2
    np.testing.assert_allclose(ens.predict_np(s, a), mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ens.predict_one(s[0], a[0]), mean[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(ens.predict(torch.tensor(s), torch.tensor(a)).numpy(), mean, atol=1e-5)
    assert not np.allclose(members[0].predict_np(s, a), members[1].predict_np(s, a))  # two different models
    # loading the ensemble again trains nothing
    load_or_train(tiny(model={"ensemble": 2}, train={"seed": 1}), tmp_path)
    assert counted["fit"] == 2
    c = DynamicsConfig.from_dict(tiny(model={"ensemble": 2}))
    with pytest.raises(DynamicsError, match=r"ensemble member 2: allowed 0..1"):
        ensemble_member(c, 2)
    with pytest.raises(DynamicsError, match=r"model.ensemble = 0: allowed"):
        DynamicsConfig.from_dict(tiny(model={"ensemble": 0}))


def test_stale_or_corrupt_cache_files_give_clear_errors(tmp_path, counted):
    load_or_train(tiny(), tmp_path)
    p, q = cache_paths(tiny(), tmp_path), cache_paths(tiny(data={"seed": 7}), tmp_path)
    # a dataset / checkpoint copied in from another config
    q["dataset"].parent.mkdir(parents=True)
    q["dataset"].write_bytes(p["dataset"].read_bytes())
    with pytest.raises(DynamicsError, match=r"generated by another data config .*python -m dynamics.train"):
        load_or_generate_dataset(tiny(data={"seed": 7}), tmp_path)
    r = cache_paths(tiny(train={"seed": 3}), tmp_path)
    r["checkpoint"].parent.mkdir(parents=True)
    r["checkpoint"].write_bytes(p["checkpoint"].read_bytes())
    with pytest.raises(DynamicsError, match=r"trained with another config .*python -m dynamics.train"):
        load_or_train(tiny(train={"seed": 3}), tmp_path)
    # truncated files
    p["checkpoint"].write_bytes(p["checkpoint"].read_bytes()[:100])
    with pytest.raises(DynamicsError, match=r"checkpoint .* is corrupt.*delete .* and retrain"):
        load_or_train(tiny(), tmp_path)
    p["dataset"].write_bytes(b"not a torch file")
    with pytest.raises(DynamicsError, match=r"dataset .* is corrupt.*regenerate it with `python -m dynamics.train`"):
        load_or_generate_dataset(tiny(), tmp_path)
    with pytest.raises(DynamicsError, match="does not exist; generate it with `python -m dynamics.train`"):
        Transitions.load(tmp_path / "nothing.pt")


def test_dataset_round_trip_and_validation(tmp_path):
    ds = synthetic_transitions(5, n_steps=2)
    ds.meta["note"] = "x"
    back = Transitions.load(ds.save(tmp_path / "d.pt"))
    assert all(np.array_equal(getattr(ds, k), getattr(back, k)) for k in ds.arrays()) and back.meta["note"] == "x"
    with pytest.raises(DynamicsError, match=r"array 's' has shape \(4, 4\), expected \(4, 5\)"):
        Transitions.from_arrays(np.zeros((4, 4)), np.zeros((4, 3)), np.zeros((4, 5)))
    with pytest.raises(DynamicsError, match=r"array 'a' has shape \(3, 3\), expected \(4, 3\)"):
        Transitions.from_arrays(np.zeros((4, 5)), np.zeros((3, 3)), np.zeros((4, 5)))
    with pytest.raises(DynamicsError, match="skill id 3"):
        Transitions.from_arrays(np.zeros((1, 5)), [[3, 0, 0]], np.zeros((1, 5)))
    with pytest.raises(DynamicsError, match="water fractions outside"):
        Transitions.from_arrays([[0, 0, 0, 0.8, 0.8]], [[0, 0, 0]], np.zeros((1, 5)))
    with pytest.raises(DynamicsError, match="NaN"):
        Transitions.from_arrays([[0, 0, np.nan, 0, 0]], [[0, 0, 0]], np.zeros((1, 5)))
    with pytest.raises(DynamicsError, match="cannot train the dynamics model on 1 transition"):
        fit(Transitions.from_arrays(np.zeros((1, 5)), np.zeros((1, 3)), np.zeros((1, 5))), SMALL)


def test_target_world_dataset_is_refused_for_training(tmp_path, monkeypatch):
    def gen(cfg, shard_dir=None, progress=False, world_cfg=None):
        ds = synthetic_generator(cfg)
        ds.meta["world"] = "target"
        return ds

    monkeypatch.setattr("dynamics.data.generate_source_dataset", gen)
    with pytest.raises(DynamicsError, match="source world only"):
        load_or_train(tiny(), tmp_path)
