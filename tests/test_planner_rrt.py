"""OMPL RRT planner: precondition, goal, depth limit, determinism, candidates, budgets, bad input.

Uses the 2-D point robot of tests.doubles.standins (embedded in the 5-D pouring state): the MDE
stand-in reports a huge deviation for any move whose path enters a wall-like box between the
start and the pouring zone, so admissible plans must go over the wall.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from planner import ActionSampler, Planner, PlannerConfig, goal_reached, rollout
from task.threads import torch_threads
from tests.doubles.standins import AnalyticPouringModel, ToyBoxMDE, ToyPointRobot

START = np.array([0.5, 0.05, 0.0, 1.0, 0.0])
GOAL = 0.5
BETA, D_MAX = 2.0, 0.07


@pytest.fixture()
def toy():
    robot = ToyPointRobot()
    return robot, ToyBoxMDE(robot)


def check_trajectory(traj, robot, mde, g, tol, beta, d_max, config):
    """Every step is admissible, consistent with the model and the MDE, and ends at the goal."""
    assert 1 <= len(traj) <= config.max_actions
    np.testing.assert_array_equal(traj.states[0], START)
    X = torch.tensor(traj.features)
    mu, sd = mde.predict(X)
    np.testing.assert_allclose(traj.mu, mu.numpy())
    np.testing.assert_allclose(traj.sigma, sd.numpy())
    assert np.all(traj.mu + beta * traj.sigma < d_max)
    assert not mde.path_hits_box(X).any()
    # the planner feeds the model float32 (torch's default dtype; the toy is not an nn.Module)
    nxt = (
        robot.predict(
            torch.tensor(traj.states[:-1], dtype=torch.float32), torch.tensor(traj.actions, dtype=torch.float32)
        )
        .double()
        .numpy()
    )
    np.testing.assert_allclose(traj.states[1:], np.clip(nxt, config.state_low, config.state_high), atol=1e-12)
    assert goal_reached(traj.final_state, g, tol, config.spill_limit)
    assert not any(goal_reached(s, g, tol, config.spill_limit) for s in traj.states[:-1])


def test_reaches_goal_and_respects_precondition(toy):
    robot, mde = toy
    cfg = PlannerConfig(time_budget=5.0)
    planner = Planner(robot, mde, cfg)
    for seed in range(5):
        r = planner.plan(START, GOAL, beta=BETA, d_max=D_MAX, seed=seed)
        assert r.found, r.stats
        assert r.stats.termination == "solved"
        assert r.stats.propagations <= cfg.propagation_budget
        check_trajectory(r.trajectory, robot, mde, GOAL, cfg.goal_tol, BETA, D_MAX, cfg)


def test_without_precondition_plans_cut_through_the_box(toy):
    """Control for the test above: the box really is in the way of unconstrained plans."""
    robot, mde = toy
    planner = Planner(robot, None, PlannerConfig(time_budget=5.0))
    hits = 0
    for seed in range(5):
        r = planner.plan(START, GOAL, seed=seed)
        assert r.found
        hits += bool(mde.path_hits_box(torch.tensor(r.trajectory.features)).any())
    assert hits >= 3


def test_precondition_parameters_are_per_call(toy):
    """beta / d_max are honoured per call: a d_max below every mu admits nothing."""
    robot, mde = toy
    planner = Planner(robot, mde, PlannerConfig(time_budget=5.0, propagation_budget=3000))
    r = planner.plan(START, GOAL, beta=0.0, d_max=0.005, seed=0)  # base deviation is 0.01
    assert not r.found
    assert r.stats.tree_size == 1
    assert r.stats.rejected == r.stats.mde_evaluations > 0
    # a very negative beta admits even the box (mu - 200 * 0.01 < 0.07 for mu = 1)
    r = planner.plan(START, GOAL, beta=-200.0, d_max=D_MAX, seed=0)
    assert r.found and r.stats.rejected == 0


def test_same_seed_same_plan_different_seed_different_plan(toy):
    robot, mde = toy
    planner = Planner(robot, mde, PlannerConfig(time_budget=5.0))
    a = planner.plan(START, GOAL, seed=11)
    b = planner.plan(START, GOAL, seed=11)
    c = planner.plan(START, GOAL, seed=12)
    assert a.found and b.found and c.found
    assert a.trajectory.same_as(b.trajectory, atol=0.0)
    assert a.stats.propagations == b.stats.propagations
    assert a.stats.tree_size == b.stats.tree_size
    assert not a.trajectory.same_as(c.trajectory)


def test_candidates_are_distinct_and_reproducible(toy):
    robot, mde = toy
    planner = Planner(robot, mde, PlannerConfig(time_budget=5.0))
    cs = planner.plan_candidates(START, GOAL, n=4, beta=BETA, d_max=D_MAX, seed=3)
    assert len(cs.runs) == 4
    assert len(cs) == sum(r.found for r in cs.runs) >= 3
    for i, a in enumerate(cs.candidates):
        for b in cs.candidates[i + 1 :]:
            assert not a.same_as(b)
    again = planner.plan_candidates(START, GOAL, n=4, beta=BETA, d_max=D_MAX, seed=3)
    assert len(again) == len(cs)
    assert all(a.same_as(b, atol=0.0) for a, b in zip(cs.candidates, again.candidates))
    assert cs.propagations == sum(r.stats.propagations for r in cs.runs)


def test_depth_limit(toy):
    """With max_actions = 3 the wall cannot be crossed in time (it takes at least 4 actions)."""
    robot, mde = toy
    cfg = PlannerConfig(max_actions=3, time_budget=5.0, propagation_budget=6000)
    r = Planner(robot, mde, cfg).plan(START, GOAL, seed=0)
    assert not r.found
    # ...and every plan found with the default limit has at most 6 actions (checked above);
    # a 2-action limit from inside the pouring zone still works:
    near = np.array([0.1, 0.1, 0.0, 1.0, 0.0])
    r = Planner(robot, mde, cfg.replace(max_actions=1)).plan(near, GOAL, seed=0)
    assert r.found and len(r.trajectory) == 1


def test_unreachable_goal_is_not_found_within_time_budget():
    robot = ToyPointRobot()
    wall = ToyBoxMDE(robot, box=(0.2, 0.3, 0.0, 0.4))  # spans the whole height: no way around
    planner = Planner(robot, wall, PlannerConfig(propagation_budget=10**9))
    t0 = time.perf_counter()
    r = planner.plan(START, GOAL, time_budget=0.5, seed=0)
    elapsed = time.perf_counter() - t0
    assert not r.found and r.trajectory is None
    assert r.stats.termination in ("time_budget", "exhausted")
    assert elapsed < 3.0
    assert r.stats.best_goal_distance > 0


def test_propagation_budget_is_exact():
    robot = ToyPointRobot()
    wall = ToyBoxMDE(robot, box=(0.2, 0.3, 0.0, 0.4))
    r = Planner(robot, wall, PlannerConfig(time_budget=30.0)).plan(START, GOAL, propagation_budget=1500, seed=0)
    assert not r.found
    assert r.stats.termination == "propagation_budget"
    assert r.stats.propagations == 1500
    assert robot.rows == 1500


def test_a_centred_aim_falls_back_to_the_most_centred_plan_of_the_wide_band(toy):
    """accept_tol: when no state within the aimed goal_tol is reached, the plan to the tree state closest
    to the goal inside the wider band is returned (deterministically); without it nothing is found."""
    robot, mde = toy
    aim, wide = 1e-7, 0.05  # an aim no continuous sample hits
    kw = dict(tol=aim, beta=BETA, d_max=D_MAX, propagation_budget=3000, seed=0)
    assert not Planner(robot, mde, PlannerConfig(time_budget=30.0)).plan(START, GOAL, **kw).found
    planner = Planner(robot, mde, PlannerConfig(time_budget=30.0, accept_tol=wide))
    r = planner.plan(START, GOAL, **kw)
    assert r.found and r.stats.termination == "accepted" and r.stats.propagations == 3000
    final = r.trajectory.final_state
    assert goal_reached(final, GOAL, wide, planner.config.spill_limit)
    assert not goal_reached(final, GOAL, aim, planner.config.spill_limit)
    assert np.all(r.trajectory.mu + BETA * r.trajectory.sigma < D_MAX)
    again = planner.plan(START, GOAL, **kw)
    np.testing.assert_array_equal(again.trajectory.actions, r.trajectory.actions)
    # up to the wide band's first hit both searches grow the same tree, so the fallback finds whatever the
    # wide band finds with the same budget, and ends at least as close to the goal
    for seed in range(4):
        kw.update(seed=seed, propagation_budget=1500)
        wide_only = Planner(robot, mde, PlannerConfig(time_budget=30.0)).plan(START, GOAL, **{**kw, "tol": wide})
        aimed = planner.plan(START, GOAL, **kw)
        assert aimed.found == wide_only.found
        if wide_only.found:
            err = [abs(p.trajectory.final_state[4] - GOAL) for p in (aimed, wide_only)]
            assert err[0] <= err[1]
    # an aim that is reached ends the search (solved), as a plan without an aim does
    hit = planner.plan(START, GOAL, tol=0.05, beta=BETA, d_max=D_MAX, seed=0)
    assert hit.found and hit.stats.termination == "solved"
    with pytest.raises(ValueError, match="accept_tol"):
        PlannerConfig(goal_tol=0.05, accept_tol=0.02)


def test_trivial_problem_returns_empty_plan(toy):
    robot, mde = toy
    s = np.array([0.1, 0.1, 0.0, 0.5, 0.5])
    r = Planner(robot, mde).plan(s, 0.5)
    assert r.found and len(r.trajectory) == 0 and r.stats.termination == "trivial"


def test_dead_start_is_unreachable(toy):
    robot, mde = toy
    spilled = np.array([0.1, 0.1, 0.0, 0.9, 0.05])  # 5 % already spilled
    r = Planner(robot, mde).plan(spilled, 0.5)
    assert not r.found and r.stats.termination == "unreachable" and r.stats.propagations == 0
    # without pruning the planner searches (and cannot succeed either: spill never decreases)
    r = Planner(robot, mde, PlannerConfig(prune_dead_states=False)).plan(spilled, 0.5, propagation_budget=500)
    assert not r.found and r.stats.termination == "propagation_budget"


def test_pouring_standin_plan_is_consistent():
    model = AnalyticPouringModel()
    planner = Planner(model, None, PlannerConfig(time_budget=5.0))
    r = planner.plan([0.45, 0.2, 0.0, 1.0, 0.0], 0.6, seed=0)
    assert r.found
    t = r.trajectory
    assert goal_reached(t.final_state, 0.6, 0.05)
    assert (t.actions[:, 0] == 1).any()  # water only moves by pouring
    np.testing.assert_array_equal(t.mu, 0.0)


@pytest.mark.parametrize(
    "start, match",
    [
        ([0.7, 0.1, 0.0, 1.0, 0.0], r"x=0\.7 outside allowed range \[0\.05, 0\.55\]"),
        ([0.3, 0.0, 0.0, 1.0, 0.0], r"y=0\.0 outside allowed range \[0\.03, 0\.35\]"),
        ([0.3, 0.1, 3.0, 1.0, 0.0], r"theta=3\.0 outside allowed range"),
        ([0.3, 0.1, 0.0, 1.2, 0.0], r"v_ctrl=1\.2 outside allowed range \[0\.0, 1\.0\]"),
        ([0.3, 0.1, 0.0, 1.0, float("nan")], r"v_tgt=nan outside allowed range"),
        ([0.3, 0.1, 0.0, 1.0], r"state vector of 5"),
    ],
)
def test_bad_start_raises(toy, start, match):
    robot, mde = toy
    with pytest.raises(ValueError, match=match):
        Planner(robot, mde).plan(start, 0.5)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(goal=1.5), r"goal g=1\.5 outside allowed range \[0, 1\]"),
        (dict(goal=-0.1), r"goal g=-0\.1 outside allowed range"),
        (dict(goal=0.5, tol=0.0), r"tol=0\.0 must be > 0"),
        (dict(goal=0.5, tol=-1), r"tol=-1 must be > 0"),
        (dict(goal=0.5, beta=float("inf")), r"beta=inf must be finite"),
        (dict(goal=0.5, time_budget=0), r"time_budget=0 must be > 0"),
        (dict(goal=0.5, propagation_budget=0), r"propagation_budget=0 must be >= 1"),
    ],
)
def test_bad_goal_or_budget_raises(toy, kwargs, match):
    robot, mde = toy
    with pytest.raises(ValueError, match=match):
        Planner(robot, mde).plan(START, **kwargs)


def test_errors_inside_callbacks_propagate_cleanly(toy):
    robot, _ = toy

    class BrokenMDE:
        def predict(self, X):
            raise ZeroDivisionError("boom")

    with pytest.raises(ZeroDivisionError, match="boom") as info:
        Planner(robot, BrokenMDE()).plan(START, GOAL)
    assert any("OMPL callback" in n for n in getattr(info.value, "__notes__", []))

    class WrongShape:
        def predict(self, states, actions):
            return states[:, :3]

    with pytest.raises(ValueError, match="dynamics model returned shape"):
        Planner(WrongShape()).plan(START, GOAL)


def _another_thread_count() -> int:
    """A count other than torch's current one (a pytest-xdist worker runs torch on 1 thread: 2 there), so that
    setting it is a change that can be seen, and restoring the old one is too."""
    return 2 if torch.get_num_threads() == 1 else 1


def test_torch_threads_holds_while_planning_and_is_restored(toy):
    robot, mde = toy

    class Watched:  # the toy MDE, noting torch's thread count at each call the planner makes
        def __init__(self):
            self.seen = []

        def predict(self, X):
            self.seen.append(torch.get_num_threads())
            return mde.predict(X)

    before, n = torch.get_num_threads(), _another_thread_count()
    watched = Watched()
    r = Planner(robot, watched, PlannerConfig(torch_threads=n)).plan(START, GOAL, seed=0)
    assert r.stats.mde_evaluations > 0 and watched.seen and set(watched.seen) == {n}
    assert torch.get_num_threads() == before
    watched.seen.clear()  # 0: torch's setting as it was
    Planner(robot, watched, PlannerConfig(torch_threads=0)).plan(START, GOAL, seed=0)
    assert watched.seen and set(watched.seen) == {before}
    assert torch.get_num_threads() == before


def test_torch_threads_zero_leaves_torch_alone():
    """The one thread setter (task.threads) of the planner, the MDE and the dynamics training: 0 keeps torch's
    setting, any other count holds inside the block only (also when the block raises)."""
    before, n = torch.get_num_threads(), _another_thread_count()
    with torch_threads(0):
        assert torch.get_num_threads() == before
    with torch_threads(n):
        assert torch.get_num_threads() == n != before
    assert torch.get_num_threads() == before
    with pytest.raises(ZeroDivisionError, match="inside"):
        with torch_threads(n):
            assert torch.get_num_threads() == n
            raise ZeroDivisionError("inside the block")
    assert torch.get_num_threads() == before
    with pytest.raises(ValueError, match="0 to leave torch's setting alone"):
        with torch_threads(-1):
            pass


def test_rollout_matches_planned_trajectory(toy):
    """The baseline's rollout reproduces a planned trajectory's states, mu and sigma exactly."""
    robot, mde = toy
    r = Planner(robot, mde).plan(START, GOAL, seed=4)
    t = rollout(robot, mde, START, r.trajectory.actions)
    assert t.same_as(r.trajectory, atol=0.0)
    np.testing.assert_array_equal(t.mu, r.trajectory.mu)
    np.testing.assert_array_equal(t.sigma, r.trajectory.sigma)
    # Random Actions baseline: 6 actions from the planner's own sampler
    acts = ActionSampler(PlannerConfig()).sample(6, np.random.default_rng(0))
    rb = rollout(robot, None, START, acts)
    assert len(rb) == 6 and rb.states.shape == (7, 5) and (rb.mu == 0).all()


def test_a_cpu_model_with_a_numpy_path_is_planned_through_it():
    """``predict_np`` (the learned model's float64 numpy twin) replaces torch's per-call overhead on the
    planner's small batches; the plan is the one the torch path gives, up to float32 rounding."""

    class NumpyTwin(AnalyticPouringModel):
        calls = 0

        def predict_np(self, s, a):
            NumpyTwin.calls += 1
            return self.predict(
                torch.as_tensor(s, dtype=torch.float64), torch.as_tensor(a, dtype=torch.float64)
            ).numpy()

    cfg = PlannerConfig(propagation_budget=3000, time_budget=60.0)
    start = np.array([0.45, 0.2, 0.0, 1.0, 0.0])
    twin = Planner(NumpyTwin(), None, cfg).plan(start, 0.5, seed=3)
    plain = Planner(AnalyticPouringModel(), None, cfg).plan(start, 0.5, seed=3)
    assert NumpyTwin.calls > 0 and twin.found and plain.found
    np.testing.assert_array_equal(twin.trajectory.actions, plain.trajectory.actions)
    np.testing.assert_allclose(twin.trajectory.states, plain.trajectory.states, atol=1e-5)
