"""Data generation: the sequence sampler, the plant-clearance split, and one tiny simulator run."""

from __future__ import annotations

import time

import numpy as np
import pytest

from dynamics import DataConfig, ModelConfig, TrainConfig, Transitions, fit, generate_transitions
from dynamics.data import SequenceSampler, plant_clearance
from sim.world import WorldConfig
from task import on_lattice


@pytest.fixture(scope="module")
def wcfg():
    from sim.world import WorldConfig

    return WorldConfig.load()


@pytest.mark.parametrize("world", ["source", "target"])
def test_sampler_gives_valid_collision_free_sequences(wcfg, world):
    from sim.skills import plan_schedule, validate_actions

    data = DataConfig(max_sim_seconds=10.0, p_keep_stuck=0.0, p_keep_stuck_pour=0.0)
    sm = SequenceSampler(data, wcfg)
    rng = np.random.default_rng(0)
    jit = np.array([0.004, -0.003, 0.02]) if world == "target" else np.zeros(3)
    obst = sm.obstacles(world, jit)
    lengths = []
    for _ in range(6):
        start, acts = sm.sample(rng, world, jit)
        d, _ = obst.sdf(sm.boundary + start)
        assert d.min() >= data.start_margin
        validate_actions(wcfg, [acts])  # every parameter inside the world's skill ranges
        assert 1 <= len(acts) <= data.max_actions
        sched = plan_schedule(wcfg, np.r_[start, 0.0], acts, obst, sm.boundary)
        assert not sched.stuck  # p_keep_stuck* = 0: stuck sequences are resampled
        assert sched.action_end[-1] * wcfg.control_dt <= data.max_sim_seconds + 1e-9
        lengths.append(len(acts))
    assert max(lengths) > 1


def test_near_target_moves_and_pours_after_them(wcfg):
    data = DataConfig(
        p_pour=0.0,
        p_pour_after_pour=0.0,
        p_near_target=1.0,
        p_pour_after_near=1.0,
        p_theta_focus=1.0,
        pour_theta_focus=(1.2, 1.4),
    )
    sm = SequenceSampler(data, wcfg)
    acts = sm.actions(np.random.default_rng(1), 6)
    assert (acts[:, 0] == [0, 1, 0, 1, 0, 1]).all()
    assert ((acts[1::2, 1] >= 1.2) & (acts[1::2, 1] <= 1.4)).all()
    moves = acts[acts[:, 0] == 0]
    lo, hi = wcfg.target_cup.x + np.array(data.near_target_dx)
    assert ((moves[:, 1] >= lo - 1e-9) & (moves[:, 1] <= hi + 1e-9)).all()
    assert ((moves[:, 2] >= data.near_target_y[0]) & (moves[:, 2] <= data.near_target_y[1])).all()


def test_plant_clearance_separates_near_and_far(wcfg):
    s = np.array(
        [
            [0.24, 0.28, 0, 1, 0],  # pour with the lip right above the big leaf
            [0.45, 0.20, 0, 1, 0],  # move on the right, far from the plant
            [0.47, 0.20, 0, 1, 0],  # pour far right, water lands right of the target cup
            [0.31, 0.28, 0, 1, 0],
        ]
    )  # lip 6 cm right of the leaf tip, above it: the stream reaches it
    a = np.array([[1, 1.5, 0.2], [0, 0.45, 0.30], [1, 1.0, 0.0], [1, 1.8, 0.2]])
    tr = Transitions.from_arrays(s, a, s)
    c = plant_clearance(wcfg, tr, "target")
    assert c[0] < 0.01 and c[1] > 0.09 and c[2] > 0.05 and c[3] < 0.01
    assert plant_clearance(wcfg, tr, "target", stream_speed=0.0)[3] > 0.03  # vertical fall line only
    assert np.isinf(plant_clearance(wcfg, tr, "source")).all()


class _NoSimulator:
    def run(self, *a, **k):
        raise AssertionError("resumed generation must not simulate finished batches again")


def test_tiny_simulator_dataset_trains_and_resumes(tmp_path):
    """Integration: 2 environments x 2 actions in the real source world, then a few epochs."""
    data = DataConfig(batch_size=2, n_batches=1, min_actions=2, max_actions=2, max_sim_seconds=5.0, seed=3)
    t0 = time.perf_counter()
    ds = generate_transitions(data, "source", progress=False, shard_dir=tmp_path)
    wall = time.perf_counter() - t0
    assert 2 <= len(ds) <= 4 and ds.meta["counts"]["trajectories"] == 2
    first = ds.step == 0
    assert np.allclose(ds.s[first, 3], 1.0, atol=0.01) and np.allclose(ds.s[first, 4], 0.0, atol=0.01)
    for t in np.unique(ds.traj):  # consecutive steps chain: s' of step k is s of step k + 1
        rows = np.flatnonzero(ds.traj == t)
        assert np.allclose(ds.s_next[rows[:-1]], ds.s[rows[1:]])
    moved = (ds.skill() == 0) & ~ds.stuck
    lattice = float(WorldConfig.load().skills.get("lattice", 0.0))  # the world moves the cup to its lattice point
    assert np.array_equal(
        ds.a[moved, 1:3], on_lattice(ds.a[moved, 1:3], lattice).astype(ds.a.dtype)
    )  # recorded as executed
    assert np.allclose(ds.s_next[moved, :2], ds.a[moved, 1:3], atol=2e-3)  # kinematic cup reaches it
    again = generate_transitions(data, "source", progress=False, shard_dir=tmp_path, executor=_NoSimulator())
    assert np.array_equal(again.s_next, ds.s_next)
    model = fit(ds, ModelConfig(hidden=(16,)), TrainConfig(max_epochs=3, patience=3))
    out = model.predict_np(ds.s, ds.a)
    assert np.isfinite(out).all() and (out[:, 3:] >= 0).all() and (out[:, 3:].sum(1) <= 1 + 1e-9).all()
    assert wall < 120


def test_focused_pours_move_next_to_the_target_cup_then_pour(wcfg):
    data = DataConfig(p_second_pour=1.0, pour_theta=(1.1, 1.3))
    sm = SequenceSampler(data, wcfg)
    rng = np.random.default_rng(2)
    for _ in range(5):
        start, acts = sm.focused_pour(rng, "source", np.zeros(3))
        assert acts[:, 0].tolist() == [0, 1, 1]
        assert data.pour_x[0] <= acts[0, 1] <= data.pour_x[1] and data.pour_y[0] <= acts[0, 2] <= data.pour_y[1]
        assert 1.1 <= acts[1, 1] <= 1.3 and acts[1, 1] <= acts[2, 1] <= acts[1, 1] + 0.4
        assert data.start_margin <= sm.obstacles("source", np.zeros(3)).sdf(sm.boundary + start)[0].min()


def test_focused_pours_are_a_new_dataset_whose_random_shards_are_reused():
    """pour_batches > 0: a new data hash; the random batches' shards keep their identity (they are reused), the
    pour batches have their own."""
    import dataclasses

    from dynamics import DynamicsConfig, data_hash
    from dynamics.data import shard_identity

    base = DynamicsConfig().replace(data=dataclasses.replace(DynamicsConfig().data, pour_batches=0))
    on = base.replace(data=dataclasses.replace(base.data, pour_batches=2))
    assert data_hash(on) != data_hash(base)
    w = WorldConfig.load()
    assert shard_identity(on.data, w) == shard_identity(base.data, w) != shard_identity(on.data, w, pours=True)
    with pytest.raises(ValueError, match=r"data.pour_batches = -1: allowed 0..inf"):
        DataConfig(pour_batches=-1)
    with pytest.raises(ValueError, match=r"data.pour_theta = \[1.5, 1.0\]"):
        DataConfig(pour_theta=(1.5, 1.0))


def test_focused_pours_are_added_to_the_cached_random_data(tmp_path):
    """load_or_generate_dataset with pour_batches: the random data's own cached dataset (not simulated again)
    followed by the focused-pour batches, whose trajectory indices come after the random ones."""
    import dataclasses

    from dynamics import DynamicsConfig
    from dynamics.train import load_or_generate_dataset

    data = DataConfig(
        batch_size=2,
        n_batches=1,
        min_actions=1,
        max_actions=1,
        max_sim_seconds=4.0,
        seed=5,
        pour_batches=1,
        p_second_pour=0.0,
    )
    cfg = DynamicsConfig(data=dataclasses.replace(data, pour_batches=0), progress=False)
    random_only = load_or_generate_dataset(cfg, tmp_path, use_shipped=False)
    both = load_or_generate_dataset(cfg.replace(data=data), tmp_path, use_shipped=False)
    n = len(random_only)
    assert np.array_equal(both.s_next[:n], random_only.s_next) and np.array_equal(both.traj[:n], random_only.traj)
    pours = both.subset(np.arange(n, len(both)))
    assert (pours.traj >= data.n_batches * data.batch_size).all() and len(np.unique(pours.traj)) == 2
    assert pours.a[pours.step == 0, 0].tolist() == [0, 0] and pours.a[pours.step == 1, 0].tolist() == [1, 1]
    assert np.allclose(pours.s[pours.step == 1, 3], 1.0, atol=0.01)  # the pour starts from a full cup
