"""The partial-pour take-apart: finding the pours in a saved set, and the summary's arithmetic (no simulation)."""

from pathlib import Path

import numpy as np
import pytest

from benchmarks.partial_pours import find_pours, set_seed, summarise, take_apart


@pytest.fixture(scope="module")
def world():
    from active.run import compose_config
    from sim.world import WorldConfig

    return WorldConfig.from_mapping(compose_config([])["world"])


def _set(world, path: Path, seed: int) -> Path:
    """A stand-in ceiling set of 3 trajectories made from ladder seed ``seed``'s problems: 0 moves then makes
    a partial first pour, 1 pours everything, 2 makes a partial first pour as its first action."""
    from active.ladder import ceiling_train_problems

    probs = ceiling_train_problems(world, 3, seed)
    st = [p.start[:3] for p in probs]
    full = lambda pose: np.r_[pose, 1.0, 0.0]  # noqa: E731
    s = np.array([full(st[0]), full([0.32, 0.17, 0.0]), full(st[1]), full(st[2])])
    a = np.array([[0, 0.32, 0.17], [1, 1.2, 0.5], [1, 2.0, 0.5], [1, 1.2, 0.3]])
    s2 = np.array([full([0.32, 0.17, 0.0]), [0.32, 0.17, 0.0, 0.6, 0.4], [*st[1], 0.0, 0.95], [*st[2], 0.7, 0.3]])
    np.savez(path, s=s, a=a, s_next=s2, trajectory=np.array([0, 0, 1, 2]), category=np.array(["successful_pour"] * 3))
    return path


def test_pours_come_with_their_history_slot_and_problem(world, tmp_path):
    path = _set(world, tmp_path / "ceiling_train_seed4.npz", 4)
    pours = find_pours(world, [path], [set_seed(path, None)])
    assert [(p["trajectory"], p["step"], p["slot"], len(p["prefix"])) for p in pours] == [(0, 1, 0, 2), (2, 0, 2, 1)]
    np.testing.assert_array_equal(pours[0]["prefix"][0], [0, 0.32, 0.17])
    np.testing.assert_array_equal(pours[0]["recorded"], [0.32, 0.17, 0.0, 0.6, 0.4])


def test_a_set_from_another_seed_is_refused(world, tmp_path):
    path = _set(world, tmp_path / "ceiling_train_seed4.npz", 4)
    with pytest.raises(
        ValueError, match=r"not at the start of ladder seed 5's problem 0 \(.*\); pass the right --set-seeds"
    ):
        find_pours(world, [path], [5])


def test_bad_arguments_are_refused_before_any_compute(tmp_path):
    with pytest.raises(ValueError, match="no seed in the file name"):
        set_seed(tmp_path / "train.npz", None)
    assert set_seed(tmp_path / "train.npz", 3) == 3
    with pytest.raises(ValueError, match="--slots 0: allowed 1..8"):
        take_apart([tmp_path / "a.npz"], None, [], 0, 8, [])
    with pytest.raises(ValueError, match="--jitters 0: allowed >= 1"):
        take_apart([tmp_path / "a.npz"], None, [], 5, 0, [])
    with pytest.raises(ValueError, match="--set-seeds: 2 seeds for 1 --sets"):
        take_apart([tmp_path / "a.npz"], [0, 1], [], 5, 1, [])
    with pytest.raises(FileNotFoundError, match="--mde: no such file"):
        take_apart([tmp_path / "a.npz"], None, [], 5, 1, [tmp_path / "mde_iter001.pt"])


def _row(model_tgt, hist, rest, source, jitter_labels):
    state = lambda v: [0.3, 0.17, 0.0, 1.0 - v, v]  # noqa: E731
    return {
        "model": state(model_tgt),
        "recorded": state(hist[0]),
        "label_recorded": 0.01,
        "history": [state(v) for v in hist],
        "rest": [state(v) for v in rest],
        "source": [state(v) for v in source],
        "labels_history": [0.01] * len(hist),
        "labels_rest": [0.02] * len(rest),
        "labels_source": [0.03] * len(source),
        "labels_jitter": jitter_labels,
        "jitter_share_good": float(np.mean(np.array(jitter_labels[1:]) < 0.07)),
    }


def test_summary_separates_history_particles_and_plant():
    rows = [
        _row(0.40, [0.42, 0.44], [0.40, 0.40], [0.40, 0.40], [0.02, 0.02, 0.02]),  # always good
        _row(0.40, [0.30, 0.30], [0.34, 0.34], [0.40, 0.40], [0.5, 0.02, 0.5]),  # the plant decides
        _row(0.40, [0.10, 0.10], [0.10, 0.10], [0.12, 0.12], [0.9, 0.9, 0.9]),
    ]  # always bad
    s = summarise(rows, 0.07)
    assert s["replay_max_abs_diff"] == 0.0
    assert s["history"]["slot_std_target_cup"] == pytest.approx(0.0)  # median of 0.01, 0, 0
    assert s["rest"]["model_error_target_cup"] == pytest.approx(0.06)  # |0.4 - 0.4|, |0.4 - 0.34|, |0.4 - 0.1|
    assert s["source"]["model_error_target_cup_signed"] == pytest.approx(0.0)
    assert s["history_minus_rest_target_cup"]["median_abs"] == pytest.approx(0.03)
    assert s["target_rest_equals_source"] == 1
    assert s["jitter"] == {
        "always_good": 1,
        "always_bad": 1,
        "mixed": 1,
        "share_good_mean": pytest.approx(0.5),
        "good_without_jitter": pytest.approx(1 / 3),
        "label_of_good_outcomes_median": 0.02,
    }


def test_plot_draws_every_pour_including_one_no_plant_pose_admitted(tmp_path):
    from benchmarks.partial_pours import plot

    rows = [
        {"x": 0.31, "y": 0.17, "theta": 1.2, "jitter_share_good": 0.5, "labels_jitter": [0.02, 0.03, 0.4]},
        {"x": 0.29, "y": 0.25, "theta": 1.3, "jitter_share_good": None, "labels_jitter": [0.02, None, None]},
    ]
    path = plot({"pours": rows, "d_max": 0.07}, tmp_path / "pours.png")
    assert path.stat().st_size > 10_000


def test_a_pour_from_rest_on_the_move_ranges_edge_stays_inside_it(world):
    from benchmarks.partial_pours import from_rest
    from sim.skills import validate_actions

    pre = np.array([0.31, np.float32(0.36), 0.0, 1.0, 0.0])  # the observed pose, a rounding above y's bound
    acts = from_rest(pre, np.array([1, 1.2, 0.5]), world.skills["move"])
    np.testing.assert_allclose(acts, [[0, 0.31, 0.36], [1, 1.2, 0.5]])
    validate_actions(world, [acts])  # would raise "move.y = 0.36 outside its range" without the clip
