"""Contact prediction with the known static geometry (sim.contact), the contact-aware dynamics
wrapper (dynamics.contact) and the planner's pruning of moves predicted stuck."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dynamics import ContactAwareDynamics
from planner import Planner, PlannerConfig
from sim.contact import ContactPredictor
from sim.skills import cup_boundary, move, plan_schedule, pour, random_actions
from sim.world import WorldConfig
from tests.doubles.standins import AnalyticPouringModel


@pytest.fixture(scope="module")
def world():
    """The default world with continuous cup positions (its default lattice is tested apart)."""
    import dataclasses

    w = WorldConfig.load()
    return dataclasses.replace(w, skills={**w.skills, "lattice": 0.0})


@pytest.fixture(scope="module")
def predictor(world):
    return ContactPredictor(world)


def _random_transitions(world, predictor, n, seed):
    rng = np.random.default_rng(seed)
    mv = world.skills["move"]
    bnd = cup_boundary(world)
    starts, acts = [], []
    while len(starts) < n:
        p = np.array([rng.uniform(*mv["x"]), rng.uniform(*mv["y"]), 0.0])
        d, _ = predictor.obstacles.sdf(bnd + p[:2])
        if d.min() > 0.005:  # start poses clear of every obstacle, as the executor requires
            starts.append(p)
            acts.append(random_actions(world, 1, rng)[0])
    return np.array(starts), np.array(acts)


def test_agrees_with_the_simulators_schedule(world, predictor):
    starts, acts = _random_transitions(world, predictor, 250, seed=3)
    bnd = cup_boundary(world)
    exact = [plan_schedule(world, s, a[None], predictor.obstacles, bnd) for s, a in zip(starts, acts)]
    ex_stuck = np.array([e.stuck for e in exact])
    stuck, stop, who = predictor.first_contact(starts, acts)
    assert ex_stuck.sum() >= 25  # the sample has real contacts to agree on
    # measured 0.99 on 400 transitions (misses: grazing contacts within the clearance)
    assert (stuck == ex_stuck).mean() >= 0.97
    both = stuck & ex_stuck
    err = np.array([np.abs(stop[i, :2] - exact[i].poses[-1, :2]).max() for i in np.flatnonzero(both)])
    assert np.median(err) < 0.003
    names = {predictor.name(int(w)) for w in who[stuck]}
    assert names <= {"target", "tank"}


def test_distance_raster_reads_the_exact_distance_near_the_obstacles(world, predictor):
    """The raster (1 mm, bilinear) gives the exact signed distance within 0.3 mm, and the same closest
    obstacle, wherever a contact is decided (distance below twice the margin); beyond its reach +inf or
    the walls' distance."""
    from sim.contact import DistanceRaster

    rng = np.random.default_rng(0)
    obst = predictor.obstacles
    raster = DistanceRaster(obst, 0.001, 2 * predictor.margin)
    p = rng.uniform(0.0, 0.6, (200_000, 2))
    exact_d, exact_i = obst.sdf(p)
    d, i = raster(p)
    close = exact_d < 2 * predictor.margin
    assert close.sum() > 5_000  # target cup and tank walls both
    assert np.abs(d[close] - exact_d[close]).max() < 3e-4
    sure = close & (np.abs(exact_d) > 0.002)  # the nearest node may lie across a junction of two obstacles' zones
    assert (i[sure] == exact_i[sure]).mean() > 0.999
    assert (d[~close] >= 2 * predictor.margin - 3e-4).all()
    with pytest.raises(ValueError, match="resolution"):
        ContactPredictor(world, resolution=0.0)


def test_raster_and_exact_distances_predict_the_same_contacts(world, predictor):
    starts, acts = _random_transitions(world, predictor, 400, seed=11)
    exact = ContactPredictor(world, resolution=None)
    s1, p1, w1 = predictor.first_contact(starts, acts)
    s2, p2, w2 = exact.first_contact(starts, acts)
    assert s2.sum() >= 40
    assert (s1 == s2).mean() >= 0.99
    both = s1 & s2
    assert np.median(np.abs(p1[both] - p2[both]).max(1)) < 1e-9  # the same first touching sample almost always
    assert (w1[both] == w2[both]).mean() >= 0.98


def test_known_cases(world, predictor):
    tx = world.target_pose()[0]
    starts = np.array([[0.45, 0.08, 0.0], [0.45, 0.30, 0.0], [0.45, 0.30, 0.0]])
    acts = np.array([move(tx, 0.08), move(0.2, 0.30), pour(1.5, 0.5)])
    stuck, stop, who = predictor.first_contact(starts, acts)
    assert stuck.tolist() == [True, False, False]
    assert predictor.name(int(who[0])) == "target"
    assert stop[0, 0] > tx + 0.05  # stopped on the target cup's right side, not at the target
    np.testing.assert_allclose(stop[1], [0.2, 0.30, 0.0])
    np.testing.assert_allclose(stop[2], starts[2])  # a free pour returns upright where it started


def test_moves_end_where_the_worlds_lattice_puts_them(world):
    """With ``skills.lattice`` a move ends on the lattice (``sim.skills.plan_schedule``), and so does
    its predicted path; without one, at the commanded target."""
    import dataclasses

    lat = ContactPredictor(dataclasses.replace(world, skills={**world.skills, "lattice": 0.01}))
    start, act = np.array([[0.45, 0.30, 0.0]]), np.array([move(0.2137, 0.3049)])
    np.testing.assert_allclose(lat.first_contact(start, act)[1][0], [0.21, 0.30, 0.0], atol=1e-12)
    np.testing.assert_allclose(ContactPredictor(world).first_contact(start, act)[1][0], [0.2137, 0.3049, 0.0])


def test_bad_arguments(world):
    with pytest.raises(ValueError, match="samples"):
        ContactPredictor(world, samples=1)
    with pytest.raises(ValueError, match="clearance"):
        ContactPredictor(world, clearance=-0.1)
    with pytest.raises(ValueError, match="world"):
        ContactPredictor(world, world="moon")


class _Commanded:
    """Stand-in model: every move arrives, every pour keeps the water (numpy and torch paths)."""

    def predict_np(self, s, a):
        out = np.array(s, float, copy=True)
        m = np.rint(a[:, 0]) == 0
        out[m, 0], out[m, 1] = a[m, 1], a[m, 2]
        return out

    def predict(self, s, a):
        return torch.as_tensor(self.predict_np(np.asarray(s, float), np.asarray(a, float)), dtype=torch.float32)


def test_wrapper_replaces_the_pose_of_stuck_actions_only(world):
    dyn = ContactAwareDynamics(_Commanded(), world)
    tx = world.target_pose()[0]
    s = np.array([[0.45, 0.08, 0.0, 1.0, 0.0], [0.45, 0.30, 0.0, 1.0, 0.0]])
    a = np.array([move(tx, 0.08), move(0.2, 0.30)])
    out = dyn.predict_np(s, a)
    assert out[0, 0] > tx + 0.05 and out[0, 3] == 1.0
    np.testing.assert_allclose(out[1], [0.2, 0.30, 0.0, 1.0, 0.0])
    torch_out = dyn.predict(torch.tensor(s, dtype=torch.float32), torch.tensor(a, dtype=torch.float32))
    np.testing.assert_allclose(torch_out.numpy(), out, atol=1e-6)
    np.testing.assert_allclose(dyn.predict_one(s[1], a[1]), out[1])


def test_planner_never_plans_a_move_predicted_stuck(world):
    dyn = ContactAwareDynamics(AnalyticPouringModel(), world)
    planner = Planner(dyn, None, PlannerConfig(time_budget=5.0))
    start = np.array([0.45, 0.08, 0.0, 1.0, 0.0])  # low, to the right of the target cup
    found = 0
    for seed in range(4):
        r = planner.plan(start, 0.6, seed=seed)
        if not r.found:
            continue
        found += 1
        t = r.trajectory
        stuck, _, _ = ContactPredictor(world).first_contact(t.states[:-1, :3], t.actions)
        moves = t.actions[:, 0] == 0
        assert not (stuck & moves).any()
    assert found >= 2


def test_planner_prunes_a_move_stopped_just_short_of_its_target(world):
    """The cup's outer wall reaches the tank wall at the very end of this move: it stops about 5 mm
    short, inside the pose rule's tolerance (``stuck_move``), so only the contact flag tells the
    planner that the simulator would end the trajectory there."""
    from planner.rrt import _Evaluator, _Search

    dyn = ContactAwareDynamics(_Commanded(), world)
    s = np.array([[0.143, 0.354, 0.0, 1.0, 0.0]])
    a = np.array([move(0.515, 0.081)])
    nxt, stuck = dyn.predict_np_contacts(s, a)
    cfg = PlannerConfig()
    assert stuck[0] and np.hypot(*(nxt[0, :2] - a[0, 1:3])) < cfg.stuck_move
    np.testing.assert_array_equal(nxt, dyn.predict_np(s, a))

    class _Fixed:  # proposes only this move
        def sample(self, k, rng):
            return np.repeat(a, k, 0)

    def refill(dynamics):
        search = _Search(
            _Evaluator(dynamics, None, _Fixed()),
            cfg,
            s[0],
            0.5,
            0.05,
            2.0,
            0.07,
            np.random.default_rng(0),
            100,
            float("inf"),
        )
        return search._refill(0, 4, 0).size

    assert refill(dyn) == 0
    assert refill(_Commanded()) == 4  # the same move without contacts is a plain transition


def test_culled_outline_distances_match_the_full_sdf_below_the_cutoff(world):
    """``Obstacles.outline_sdf`` (the schedule's contact test, culled per pose and obstacle) gives the
    full ``Obstacles.sdf``'s distance and obstacle wherever that is below the cutoff, and never less
    than the cutoff elsewhere, on cup paths of random trajectories that touch the plant, cup and walls."""
    from sim.execute import PouringExecutor
    from sim.problems import sample_problems
    from sim.skills import to_world, validate_actions

    ex = PouringExecutor(world)
    rng = np.random.default_rng(5)
    probs = sample_problems(world, 12, 5)
    cutoff, touched = 0.004, 0
    for p in probs:
        obst = ex._obstacles(world.scene("target", p.start[:3], p.plant_jitter))
        acts = validate_actions(world, [random_actions(world, 4, rng)])[0]
        poses = plan_schedule(world, np.asarray(p.start[:3], float), acts, obst, ex._boundary).poses
        d, idx = obst.outline_sdf(ex._boundary, poses, cutoff)
        full_d, full_i = obst.sdf(to_world(ex._boundary, poses, portable=True).reshape(-1, 2))
        full_d, full_i = full_d.reshape(d.shape), full_i.reshape(d.shape)
        close = full_d < cutoff
        touched += close.any(1).sum()
        np.testing.assert_array_equal(d[close], full_d[close])
        np.testing.assert_array_equal(idx[close], full_i[close])
        assert (d[~close] >= cutoff).all()
    assert touched > 20  # the paths did come close to something
    ex.close()
