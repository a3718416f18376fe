"""Pouring worlds: skills, state, outcomes, batching and bad input (one shared solver per world run)."""

import numpy as np
import pytest

from sim.execute import PouringExecutor, categorise
from sim.problems import sample_problems
from sim.skills import move, pour
from sim.world import WorldConfig, goal_reached, spill, state_distance

SCRIPTS = [
    ([0.42, 0.20], [pour(0.0, 0.5)]),  # 0: no tilt
    ([0.42, 0.20], [move(0.31, 0.14), pour(2.2, 1.0)]),  # 1: full tilt over the target, below the canopy
    ([0.42, 0.20], [move(0.42, 0.30), move(0.25, 0.30), pour(1.2, 0.5)]),  # 2: above the leaves
    ([0.42, 0.24], [move(0.15, 0.24), pour(2.0, 0.5)]),  # 3: straight through a leaf
]


@pytest.fixture(scope="module")
def cfg():
    return WorldConfig.load()


@pytest.fixture(scope="module")
def executor(cfg):
    ex = PouringExecutor(cfg)
    yield ex
    ex.close()


@pytest.fixture(scope="module")
def runs(executor):
    starts = np.array([s for s, _ in SCRIPTS])
    acts = [a for _, a in SCRIPTS]
    return {w: executor.run(w, starts, acts, goals=[0.5] * len(SCRIPTS)) for w in ("source", "target")}


def test_pour_at_zero_angle_moves_no_water(runs):
    for world in ("source", "target"):
        r = runs[world][0]
        assert r.states[-1, 3] == 1.0 and r.states[-1, 4] == 0.0
        assert r.category == "other"


def test_full_tilt_over_target_fills_it_in_source_world(runs):
    r = runs["source"][1]
    assert r.states[-1, 4] > 0.7, r.states[-1]
    assert r.category == "successful_pour" or r.final_spill > 0.02
    assert len(r.steps) == 2 and not r.stuck


def test_pour_from_above_the_leaves_spills_more_in_target_world(runs):
    src, tgt = runs["source"][2], runs["target"][2]
    assert tgt.final_spill > src.final_spill + 0.2, (src.final_spill, tgt.final_spill)
    assert tgt.category == "unsuccessful_pour"


def test_path_through_a_leaf_is_stuck(runs):
    tgt, src = runs["target"][3], runs["source"][3]
    assert tgt.stuck and tgt.stuck_on == "plant" and tgt.category == "stuck_in_plant"
    assert len(tgt.steps) == 2 and tgt.steps[0].stuck  # the pour after it never runs: under the default
    np.testing.assert_array_equal(tgt.steps[1].s_next, tgt.steps[1].s)  # on_contact "stuck", tried without effect
    assert tgt.states[-1, 0] > 0.2  # stopped at contact, short of x = 0.15
    assert not src.stuck and len(src.steps) == 2


def test_steps_chain_states(runs):
    for b, r in enumerate(runs["target"]):
        for t, st in enumerate(r.steps):
            np.testing.assert_array_equal(st.s, r.states[t])
            np.testing.assert_array_equal(st.s_next, r.states[t + 1])
        np.testing.assert_allclose(r.states[0], [*SCRIPTS[b][0], 0, 1, 0], atol=1e-6)


def test_batch_independence_and_determinism(executor, runs):
    """Re-running with different actions in environments 2 and 3 leaves 0 and 1 bit-identical."""
    starts = np.array([s for s, _ in SCRIPTS])
    acts = [SCRIPTS[0][1], SCRIPTS[1][1], [pour(0.5, 0.0)], [move(0.45, 0.1)]]
    again = executor.run("target", starts, acts)
    for b in (0, 1):
        np.testing.assert_array_equal(again[b].states, runs["target"][b].states)
    assert not np.array_equal(again[3].states[-1], runs["target"][3].states[-1])


def test_a_trajectory_keeps_its_result_in_another_batch_with_its_slot(executor, runs):
    """What the lockstep runner relies on: trajectory 2 run in a batch of 6, in another position, next
    to other trajectories, with its slot (2) gives its result bit for bit; with another slot its water
    is sampled differently."""
    starts = np.array([SCRIPTS[k][0] for k in (3, 0, 2, 0, 2, 0)])
    acts = [SCRIPTS[k][1] for k in (3, 0, 2, 0, 2, 0)]
    moved = executor.run("target", starts, acts, slots=[3, 0, 2, 4, 5, 6])
    np.testing.assert_array_equal(moved[2].states, runs["target"][2].states)
    np.testing.assert_array_equal(moved[0].states, runs["target"][3].states)
    assert not np.array_equal(moved[4].states, runs["target"][2].states)  # the same scene, slot 5
    with pytest.raises(Exception, match="slots must be 6 integers >= 0"):
        executor.run("target", starts, acts, slots=[0, 1, 2])


def test_freezing_finished_environments_changes_no_result(executor, runs):
    """Environments whose trajectory ended are frozen by default; simulating them to the end of the
    longest trajectory instead gives bit-identical observations for every trajectory, in less work."""
    starts = np.array([s for s, _ in SCRIPTS])
    full = executor.run("target", starts, [a for _, a in SCRIPTS], goals=[0.5] * len(SCRIPTS), freeze_done=False)
    frozen_work = executor.last_timing
    for a, b in zip(full, runs["target"]):
        np.testing.assert_array_equal(a.states, b.states)
        assert (a.category, a.goal_reached, a.stuck_on) == (b.category, b.goal_reached, b.stuck_on)
    again = executor.run("target", starts, [a for _, a in SCRIPTS], goals=[0.5] * len(SCRIPTS))
    assert again[0].states.tolist() == runs["target"][0].states.tolist()
    assert executor.last_timing["env_ticks_run"] < frozen_work["env_ticks_run"] == frozen_work["env_ticks"]


def test_categories():
    full = np.array([0.4, 0.2, 0, 1.0, 0.0])
    good = np.array([0.3, 0.14, 0, 0.4, 0.6])
    bad = np.array([0.3, 0.3, 0, 0.4, 0.1])
    assert categorise(np.stack([full, good]), None, False, 0.02) == "successful_pour"
    assert categorise(np.stack([full, bad]), None, False, 0.02) == "unsuccessful_pour"
    assert categorise(np.stack([full, full]), "plant", False, 0.02) == "stuck_in_plant"
    assert categorise(np.stack([full, full]), "target", False, 0.02) == "other"
    assert categorise(np.stack([full, good]), None, True, 0.02) == "other"


def test_state_helpers():
    s = np.array([0.3, 0.14, 0.0, 0.39, 0.6])
    assert spill(s) == pytest.approx(0.01)
    assert goal_reached(s, 0.62, 0.05) and not goal_reached(s, 0.5, 0.05)
    assert not goal_reached(np.array([0, 0, 0, 0.3, 0.6]), 0.6, 0.05)  # spill 0.1
    d = state_distance(s, s + np.array([0.03, 0.04, 0.0, 0.1, -0.1]))
    assert d == pytest.approx(0.05 + 0.2)
    assert state_distance(s, s, {"pose": 2.0, "volume": 0.5}) == 0.0


def test_problem_sampler_is_seeded_and_in_range(cfg):
    a = sample_problems(cfg, 5, seed=3)
    b = sample_problems(cfg, 5, seed=3)
    for p, q in zip(a, b):
        np.testing.assert_array_equal(p.start, q.start)
        assert p.goal == q.goal
    for p in a:
        assert cfg.problems["start_x"][0] <= p.start[0] <= cfg.problems["start_x"][1]
        assert cfg.problems["goal"][0] <= p.goal <= cfg.problems["goal"][1]
        assert np.all(np.abs(p.plant_jitter[:2]) <= cfg.plant["jitter_xy"])
    assert all((p.plant_jitter == 0).all() for p in sample_problems(cfg, 3, seed=0, world="source"))


def test_a_lattice_puts_starts_and_move_targets_on_it(cfg):
    """``skills.lattice``: every cup position on multiples of the spacing; absent, positions stay as drawn."""
    import dataclasses

    from sim.skills import Obstacles, cup_boundary, plan_schedule

    assert cfg.skills["lattice"] == 0.01  # the default world's
    lat, cfg = cfg, dataclasses.replace(cfg, skills={**cfg.skills, "lattice": 0.0})
    free = sample_problems(cfg, 6, seed=3)
    snapped = sample_problems(lat, 6, seed=3)
    for p, q in zip(free, snapped):
        np.testing.assert_allclose(q.start[:2], np.round(p.start[:2], 2), atol=1e-12)
        assert p.goal == q.goal and not np.allclose(p.start[:2], q.start[:2])
    obst = Obstacles(cfg.obstacle_bodies("source"), np.full(2, 0.03), np.full(2, 0.57))
    acts = np.array([move(0.3137, 0.2261)])
    for world_cfg, end in ((cfg, [0.3137, 0.2261]), (lat, [0.31, 0.23])):
        sched = plan_schedule(world_cfg, np.array([0.42, 0.20, 0.0]), acts, obst, cup_boundary(cfg))
        np.testing.assert_allclose(sched.poses[-1, :2], end, atol=1e-12)
    with pytest.raises(ValueError, match=r"world.skills.lattice = -0.01: allowed 0"):
        WorldConfig.from_mapping({**dataclasses.asdict(cfg), "skills": {**cfg.skills, "lattice": -0.01}})


def test_plant_on_contact_hold_blocks_only_that_action(cfg):
    """``plant.on_contact: hold``: a move blocked by a leaf stops there and the trajectory goes on from the
    blocked pose; "stop" (and any rigid obstacle under "hold") ends it. Schedules only, no simulation."""
    import dataclasses

    from sim.skills import Obstacles, cup_boundary, plan_schedule

    assert cfg.plant_on_contact == "stuck"  # the default: schedules as "stop"
    hold = dataclasses.replace(cfg, plant={**cfg.plant, "on_contact": "hold"})
    obst = Obstacles(cfg.obstacle_bodies("target"), np.full(2, 0.03), np.full(2, 0.57))
    start, acts = np.array([0.42, 0.24, 0.0]), np.array([move(0.15, 0.24), move(0.42, 0.24), pour(0.5, 0.2)])
    stop = plan_schedule(cfg, start, acts, obst, cup_boundary(cfg))
    held = plan_schedule(hold, start, acts, obst, cup_boundary(cfg))
    assert (stop.executed, stop.blocked, stop.stuck_on) == (1, [0], "plant")
    assert (held.executed, held.blocked, held.stuck_on, held.stuck) == (3, [0], "plant", True)
    k = held.action_end[0]
    np.testing.assert_array_equal(held.poses[: k + 1], stop.poses)  # the same blocked move
    assert held.poses[k, 0] > 0.2  # held at the leaf, short of x = 0.15
    np.testing.assert_allclose(held.poses[held.action_end[1], :2], [0.42, 0.24])  # then the next move runs
    rigid = plan_schedule(
        hold, np.array([0.42, 0.20, 0.0]), np.array([move(0.22, 0.07), pour(0.5, 0.2)]), obst, cup_boundary(cfg)
    )
    assert (rigid.executed, rigid.blocked, rigid.stuck_on) == (1, [0], "target")  # the target cup still ends it
    with pytest.raises(ValueError, match=r"world.plant.on_contact = 'bend': allowed stop, hold, stuck"):
        WorldConfig.from_mapping({**dataclasses.asdict(cfg), "plant": {**cfg.plant, "on_contact": "bend"}})


def test_plant_on_contact_stuck_records_the_actions_left_without_effect(cfg, runs):
    """``plant.on_contact: stuck``: the same simulation as "stop" (final state and category bit for bit), plus one
    step per action the plant kept the cup from, with s' = s; a trajectory the plant did not stop is unchanged."""
    import dataclasses

    assert cfg.plant_on_contact == "stuck"  # the default: ``runs`` holds its trajectories
    ex = PouringExecutor(dataclasses.replace(cfg, plant={**cfg.plant, "on_contact": "stop"}))
    try:
        got = ex.run(
            "target",
            np.array([SCRIPTS[3][0], SCRIPTS[1][0]]),
            [SCRIPTS[3][1], SCRIPTS[1][1]],
            goals=[0.5, 0.5],
            slots=[3, 1],
        )
    finally:
        ex.close()
    stop_through_leaf, stop_clear = got
    through, clear = runs["target"][3], runs["target"][1]
    assert stop_through_leaf.category == through.category == "stuck_in_plant"
    assert (len(stop_through_leaf.steps), len(through.steps)) == (1, 2)
    np.testing.assert_array_equal(through.states[:2], stop_through_leaf.states)
    np.testing.assert_array_equal(through.steps[1].s, stop_through_leaf.states[-1])
    np.testing.assert_array_equal(through.steps[1].s_next, stop_through_leaf.states[-1])
    np.testing.assert_array_equal(through.steps[1].a, SCRIPTS[3][1][1])
    assert through.steps[1].stuck and len(through.actions) == 2
    assert through.goal_reached == stop_through_leaf.goal_reached
    np.testing.assert_array_equal(clear.states, stop_clear.states)
    assert len(clear.steps) == len(stop_clear.steps) and clear.category == stop_clear.category


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"world": "moon"}, "world = 'moon'"),
        ({"actions": [[pour(3.0, 0.5)]]}, r"pour.theta = 3 outside its range \[0, 2.2\]"),
        ({"actions": [[move(0.9, 0.1)]]}, "move.x"),
        ({"actions": [[]]}, "non-empty"),
        ({"actions": [[pour(0.1, 0.1)] * 7]}, "max_actions = 6"),
        ({"actions": [[[5, 0.1, 0.1]]]}, "skill id 5"),
        ({"goals": [1.5]}, r"fractions in \[0, 1\]"),
        ({"starts": np.array([[0.30, 0.10]])}, "overlaps the target body"),
    ],
)
def test_bad_input_fails_before_simulating(cfg, kwargs, match):
    ex = PouringExecutor(cfg)
    args = {"world": "target", "starts": np.array([[0.42, 0.2]]), "actions": [[pour(0.1, 0.1)]]}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        ex.run(**args)
    assert ex._solvers == {}  # nothing was built or simulated


def test_start_obstacles_names_what_run_refuses(cfg):
    """start_obstacles says per start what run would refuse (the same check), without simulating."""
    ex = PouringExecutor(cfg)
    starts = np.array([[0.30, 0.10], [0.42, 0.20]])
    assert ex.start_obstacles("target", starts) == ["target body", None]
    assert ex.start_obstacles("target", starts[1:], np.array([[0.008, 0.008, 0.05]])) == [None]
    with pytest.raises(ValueError, match="overlaps the target body"):
        ex.run("target", starts[:1], [[pour(0.1, 0.1)]])
    assert ex._solvers == {}


def test_schedules_from_worker_processes_equal_the_threads_ones(cfg, monkeypatch):
    """Large batches compute their cup schedules in spawned processes (GPU boxes): the same schedules,
    in order, and a start inside an obstacle is refused the same way."""
    import sim.execute as execute
    from sim.skills import random_actions, validate_actions

    rng = np.random.default_rng(4)
    probs = sample_problems(cfg, 12, 4)
    starts = np.array([p.start[:3] for p in probs])
    specs = [cfg.scene("target", s, p.plant_jitter) for s, p in zip(starts, probs)]
    acts = validate_actions(cfg, [random_actions(cfg, 4, rng) for _ in probs])
    ex = PouringExecutor(cfg)
    threads = ex._schedules(specs, starts, acts)
    monkeypatch.setattr(execute, "SCHEDULE_PROCESS_MIN_BATCH", 4)
    monkeypatch.setattr(execute, "SCHEDULE_PROCESS_MIN_CPUS", 1)
    try:
        procs = ex._schedules(specs, starts, acts)
        assert ex._schedule_pool is not None  # the process path ran
        for a, b in zip(threads, procs):
            np.testing.assert_array_equal(a.poses, b.poses)
            assert (a.action_end, a.executed, a.stuck_on, a.blocked) == (
                b.action_end,
                b.executed,
                b.stuck_on,
                b.blocked,
            )
        bad = starts.copy()
        bad[5] = [0.30, 0.10, 0.0]  # inside the target cup
        with pytest.raises(ValueError, match=r"starts\[5\].*overlaps the target body"):
            ex._schedules([cfg.scene("target", s, p.plant_jitter) for s, p in zip(bad, probs)], bad, acts)
    finally:
        ex.close()
    assert ex._schedule_pool is None


def test_actions_come_back_as_executed_on_the_lattice(cfg):
    """A move target is returned rounded to ``skills.lattice``, where the cup really goes, so a recorded
    transition pairs the outcome with the action that produced it; pours and continuous worlds are untouched."""
    from sim.skills import validate_actions

    lat = WorldConfig.from_mapping(
        {
            **cfg.__dict__,
            "controlled_cup": cfg.controlled_cup.__dict__,
            "target_cup": cfg.target_cup.__dict__,
            "skills": {**cfg.skills, "lattice": 0.01},
        }
    )
    cont = WorldConfig.from_mapping(
        {
            **cfg.__dict__,
            "controlled_cup": cfg.controlled_cup.__dict__,
            "target_cup": cfg.target_cup.__dict__,
            "skills": {**cfg.skills, "lattice": 0.0},
        }
    )
    seq = [move(0.3337, 0.2149), pour(1.234, 0.567)]
    (a,) = validate_actions(lat, [seq])
    np.testing.assert_allclose(a, [[0, 0.33, 0.21], [1, 1.234, 0.567]], rtol=0, atol=1e-12)
    (b,) = validate_actions(cont, [seq])
    np.testing.assert_array_equal(b, np.asarray(seq, float))


def test_parameters_clip_when_configured(cfg):
    from sim.skills import validate_actions

    clipped = WorldConfig.from_mapping(
        {
            **cfg.__dict__,
            "controlled_cup": cfg.controlled_cup.__dict__,
            "target_cup": cfg.target_cup.__dict__,
            "skills": {**cfg.skills, "clip_parameters": True},
        }
    )
    (a,) = validate_actions(clipped, [[pour(3.0, 2.0)]])
    np.testing.assert_allclose(a[0], [1, 2.2, 1.0])
