"""nanobind reference-leak warnings of the OMPL bindings must not reach the user's console.

nanobind prints "nanobind: leaked N instances!" to stderr at interpreter exit for every
binding object still alive then. The planner keeps all OMPL objects local to one run (results
are numpy only, callback exceptions are stored without their frames), so nothing is left.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = textwrap.dedent("""
    import numpy as np
    from planner import Planner, PlannerConfig
    from tests.doubles.standins import ToyBoxMDE, ToyPointRobot

    robot = ToyPointRobot()
    planner = Planner(robot, ToyBoxMDE(robot), PlannerConfig(time_budget=5.0))
    start = np.array([0.5, 0.05, 0.0, 1.0, 0.0])
    RESULT = planner.plan(start, 0.5, seed=0)                      # kept alive until exit
    CANDS = planner.plan_candidates(start, 0.5, n=2, seed=1)
    MISS = planner.plan(start, 0.5, propagation_budget=50, seed=2)  # a 'not found'

    class Broken:
        def predict(self, X):
            raise RuntimeError("broken MDE")

    try:
        Planner(robot, Broken()).plan(start, 0.5)
    except RuntimeError as e:
        ERR = e                                                     # kept alive until exit
    print("found", RESULT.found, len(CANDS), MISS.found)
    print(RESULT.trajectory.actions.tobytes().hex())
""")


@pytest.fixture(scope="module")
def script_run() -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_planning_script_stderr_has_no_leak_warnings(script_run):
    proc = script_run
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("found True")
    assert "leak" not in proc.stderr.lower(), proc.stderr[-3000:]


def test_same_seed_same_plan_across_processes(script_run):
    """OMPL's global RNG is reseeded per run, so a fresh process reproduces this one's plan."""
    import numpy as np

    from planner import Planner, PlannerConfig
    from tests.doubles.standins import ToyBoxMDE, ToyPointRobot

    robot = ToyPointRobot()
    planner = Planner(robot, ToyBoxMDE(robot), PlannerConfig(time_budget=5.0))
    planner.plan([0.5, 0.05, 0.0, 1.0, 0.0], 0.5, seed=5)  # advance OMPL's RNG state first
    here = planner.plan(np.array([0.5, 0.05, 0.0, 1.0, 0.0]), 0.5, seed=0)
    proc = script_run
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[1] == here.trajectory.actions.tobytes().hex()
