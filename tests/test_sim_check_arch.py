"""The CPU/GPU agreement check's comparison rule (the GPU run itself needs a GPU: python -m benchmarks.check_arch)."""

import numpy as np

from benchmarks.check_arch import compare


def _suite(arch, states, cats, unstable=None):
    n = len(states)
    return {
        "arch": arch,
        "final_states": np.asarray(states, float).tolist(),
        "categories": cats,
        "executed": [2] * n,
        "unstable": unstable or [False] * n,
        "wall_seconds": 1.0,
    }


def test_identical_runs_pass():
    s = [[0.3, 0.2, 0.0, 0.5, 0.5]] * 4
    out = compare(_suite("cpu", s, ["other"] * 4), _suite("gpu", s, ["other"] * 4))
    assert out["passed"] and out["max_pose_difference"] == 0 and out["category_agreement"] == 1


def test_a_pose_difference_fails_but_a_single_splash_does_not():
    a = [[0.3, 0.2, 0.0, 0.5, 0.5]] * 10
    splash = [row[:] for row in a]
    splash[3] = [0.3, 0.2, 0.0, 0.5, 0.4]  # one trajectory's fraction off by 0.1: mean 0.01
    assert compare(_suite("cpu", a, ["x"] * 10), _suite("gpu", splash, ["x"] * 10))["passed"]
    moved = [row[:] for row in a]
    moved[0] = [0.31, 0.2, 0.0, 0.5, 0.5]
    assert not compare(_suite("cpu", a, ["x"] * 10), _suite("gpu", moved, ["x"] * 10))["passed"]


def test_unstable_environment_or_category_mismatch_fails():
    a = [[0.3, 0.2, 0.0, 0.5, 0.5]] * 4
    flagged = _suite("gpu", a, ["x"] * 4, unstable=[True, False, False, False])
    assert not compare(_suite("cpu", a, ["x"] * 4), flagged)["passed"]
    assert not compare(_suite("cpu", a, ["x"] * 4), _suite("gpu", a, ["x", "y", "y", "x"]))["passed"]
