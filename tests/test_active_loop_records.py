"""What the active-learning loop records, on CI-sized runs of the tiny experiment (one method, the smallest batches
the tiny preset's counts give): a planner call that raises is counted (``plan_errors``) as a plan not found and the
run goes on; a lockstep run of two seeds stopped after an iteration resumes to more iterations with the results of
a straight run.

Every run here simulates with one :class:`sim.execute.PouringExecutor` (``active.run`` makes one per run): its first
batch of each size compiles the solver's kernels (about 25 s on 2 cores without Taichi's cache), and which executor
runs a batch changes no result (``MPMSolver.reset``; the comparisons below hold either way). The settings keep every
batch at 1 or 2 trajectories. The dynamics model is the default one where it ships (no simulation, no training),
otherwise the tiny model of ``tests/test_active_run.py``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
import torch

from active.io import read_csv
from active.loop import TIMING_FIELDS
from active.run import compose_config, run_experiment
from tests.test_active_run import tiny_overrides

METHOD = "active_balanced"


def _default_dynamics_ships() -> bool:
    """Whether every member of the default dynamics model (the one ``experiment=tiny`` uses) ships."""
    from dynamics import train as train_mod
    from dynamics.config import single_models
    from dynamics.train import cache_paths

    cfg = compose_config(["experiment=tiny"])
    members = single_models(train_mod._as_config(cfg["dynamics"]))
    return all(
        train_mod.shipped_model_path(cache_paths(m, None, cfg["world"])["model_hash"]).is_file() for m in members
    )


def _overrides(cache: Path, *extra: str) -> list[str]:
    """The tiny experiment, one method, planning in-process (``planner.workers=1``: a monkeypatched planner acts)."""
    tiny = tiny_overrides(cache)
    if _default_dynamics_ships():  # the shipped members are copied into the cache: nothing to simulate or train
        tiny = [
            o
            for o in tiny
            if not o.startswith("dynamics.") or o.split("=")[0] in ("dynamics.cache_root", "dynamics.progress")
        ]
    return tiny + ["planner.workers=1", f"method={METHOD}", *extra]


class _KeptExecutor:
    """An executor that outlives the run that asked for it (``close`` is left to the module)."""

    def __init__(self, executor):
        self._executor = executor

    def __getattr__(self, name):
        return getattr(self._executor, name)

    def close(self) -> None:
        pass


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("dynamics-cache")


@pytest.fixture(scope="module", autouse=True)
def one_executor():
    import active.run
    from sim.execute import PouringExecutor

    made: list[tuple] = []  # (world config, executor)

    def shared(world):
        for w, ex in made:
            if w == world:
                return _KeptExecutor(ex)
        made.append((world, PouringExecutor(world)))
        return _KeptExecutor(made[-1][1])

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(active.run, "PouringExecutor", shared)
        yield
    for _, ex in made:
        ex.close()


def _comparable(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in row.items() if k not in TIMING_FIELDS} for row in rows]


def test_a_planner_call_that_raises_is_a_plan_not_found_and_the_run_goes_on(cache, tmp_path, monkeypatch, caplog):
    """The first training plan that finds a plan raises instead: the loop records it as a run that found nothing
    (its problem's candidates are the runs of its set that found one, less the failed one; ``plan_errors`` of its
    iteration is 1, of the other 0) and the run finishes both iterations."""
    import planner.rrt

    over = _overrides(cache)
    beta_train = set(compose_config(over)["experiment"]["beta_train"])
    real, runs, failed = planner.rrt.Planner.plan, [], []

    def flaky(self, start, goal, **kwargs):
        result = real(self, start, goal, **kwargs)
        if kwargs.get("beta") in beta_train:  # a training candidate's run (the test plans use beta_test)
            runs.append((float(goal), kwargs["beta"], result.found))
            if not failed and result.found:
                failed.append(len(runs) - 1)
                raise RuntimeError("simulated planner failure")
        return result

    monkeypatch.setattr(planner.rrt.Planner, "plan", flaky)  # the class the in-process pool plans with
    out = tmp_path / "flaky"
    with caplog.at_level(logging.WARNING, logger="planner.pool"):
        run_experiment(compose_config(over), out)
    assert len(failed) == 1, "no training run found a plan: nothing to fail"
    goal, beta, _ = runs[failed[0]]
    siblings = [k for k, (g, b, _) in enumerate(runs) if (g, b) == (goal, beta)]  # the runs of its candidate set
    assert len(siblings) == int(compose_config(over)["experiment"]["candidates"])
    found_after = sum(runs[k][2] for k in siblings if k != failed[0])

    rows = read_csv(out / METHOD / "results.csv")
    assert [int(r["iteration"]) for r in rows] == [1, 2]  # the run went on to its end
    it = next(int(r["iteration"]) for r in rows if float(r["beta"]) == beta)  # the iteration that planned with beta
    assert [int(r["plan_errors"]) for r in rows] == [int(i == it) for i in (1, 2)]
    mine = [
        c
        for c in read_csv(out / METHOD / "categories.csv")
        if int(c["iteration"]) == it and float(c["goal"]) == round(goal, 4)
    ]
    assert len(mine) == 1
    assert int(mine[0]["n_candidates"]) == found_after  # the failed run counts as a run that found nothing
    if found_after == 0:  # it was the set's only plan: the problem fell back to random actions
        assert mine[0]["source"] == "fallback"
    assert "a plan failed and is recorded as not found" in caplog.text
    assert "RuntimeError: simulated planner failure" in caplog.text


def test_lockstep_over_two_seeds_resumes_to_more_iterations_with_the_straight_results(cache, tmp_path):
    """runner=lockstep, seeds [0, 1]: a run of 1 iteration (as a run killed once its first iteration is saved),
    rerun in the same folder with 2 iterations, resumes each seed at iteration 2 (iteration 1 is kept as it was
    written, its timings included) and ends with the results of a straight 2-iteration run (timings aside)."""
    over = _overrides(
        cache, "runner=lockstep", "seeds=[0,1]", "experiment.trajectories_per_iteration=1", "experiment.test_problems=1"
    )
    straight = tmp_path / "straight"
    run_experiment(compose_config(over), straight)
    out = tmp_path / "resumed"
    run_experiment(compose_config(over + ["experiment.iterations=1"]), out)
    first = {s: read_csv(out / f"seed{s}" / METHOD / "results.csv") for s in (0, 1)}
    assert [[int(r["iteration"]) for r in first[s]] for s in (0, 1)] == [[1], [1]]
    run_experiment(compose_config(over), out)
    for s in (0, 1):
        got, want = out / f"seed{s}" / METHOD, straight / f"seed{s}" / METHOD
        rows = read_csv(got / "results.csv")
        assert [int(r["iteration"]) for r in rows] == [1, 2] and int(rows[0]["seed"]) == s
        assert rows[0] == first[s][0]  # resumed: iteration 1 was not run again
        assert _comparable(rows) == _comparable(read_csv(want / "results.csv"))
        for name in ("categories.csv", "calibration.csv", "tests.csv"):
            assert read_csv(got / name) == read_csv(want / name), name
        a, b = torch.load(got / "dataset.pt"), torch.load(want / "dataset.pt")
        assert torch.equal(a["X"], b["X"]) and torch.equal(a["y"], b["y"])
        assert read_csv(out / f"seed{s}" / "model_only.csv") == read_csv(straight / f"seed{s}" / "model_only.csv")


@pytest.fixture(scope="module")
def three_methods(cache, tmp_path_factory) -> Path:
    """One round of active_balanced, random_plan and the oracle bound scored both ways: by the test planner's success
    on 2 held-out problems (``oracle``) and by the admission gap on 4 held-out trajectories (``oracle_admission``)."""
    out = tmp_path_factory.mktemp("three-methods")
    over = [o for o in _overrides(cache) if not o.startswith("method=")]
    over += [
        "method=all",
        f"experiment.methods=[{METHOD},random_plan,oracle,oracle_admission]",
        "experiment.iterations=1",
        "methods.oracle.validation_problems=2",
        "+methods.oracle_admission._target_=active.methods.OracleBound",
        "+methods.oracle_admission.score=admission",
        "+methods.oracle_admission.validation_trajectories=4",
    ]
    run_experiment(compose_config(over), out)
    return out


def _rows(out: Path, method: str, name: str) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "method"} for r in read_csv(out / method / name)]


def test_methods_draw_common_random_numbers_so_round_one_is_the_same_for_every_planning_method(three_methods):
    """Common random numbers: the planning seeds and the pick among candidates are keyed on (seed, purpose,
    iteration, index), never on the method. active_balanced has no MDE in round 1, so it picks at random like
    random_plan, from the same stream: the two runs execute the same trajectories, fit the same MDE and record the
    same rows (method and timings aside) in every file of round 1."""
    out = three_methods
    for name in ("categories.csv", "tests.csv", "calibration.csv"):
        assert _rows(out, METHOD, name) == _rows(out, "random_plan", name), name
    assert _comparable(_rows(out, METHOD, "results.csv")) == _comparable(_rows(out, "random_plan", "results.csv"))
    assert {r["source"] for r in _rows(out, METHOD, "categories.csv")} <= {"plan", "fallback"}
    a, b = (torch.load(out / m / "dataset.pt") for m in (METHOD, "random_plan"))
    assert len(a["y"]) > 0 and torch.equal(a["X"], b["X"]) and torch.equal(a["y"], b["y"])


def test_the_oracle_chooses_among_the_same_candidates_after_executing_them_and_keeps_one_per_problem(three_methods):
    """Both oracles plan the same candidate sets as random_plan in round 1 (no MDE yet, the same seeds), execute
    them all and keep one trajectory per problem, so their datasets hold exactly their kept trajectories'
    transitions; the admission-scored one keeps its validation set (4 trajectories, its own problems) in its state."""
    from active.rundir import load_state

    out = three_methods
    theirs = _rows(out, "random_plan", "categories.csv")
    for oracle in ("oracle", "oracle_admission"):
        mine = _rows(out, oracle, "categories.csv")
        assert [(r["goal"], r["n_candidates"]) for r in mine] == [(r["goal"], r["n_candidates"]) for r in theirs]
        assert {r["source"] for r in mine} <= {"plan", "fallback"}
        st = load_state(out / oracle / "state.pt")
        steps = sum(int(r["steps"]) for r in mine)
        assert len(st["y"]) == steps and len(st["X"]) == steps
        assert ("validation" in st) == (oracle == "oracle_admission")
    st = load_state(out / "oracle_admission" / "state.pt")
    assert len(st["validation"]["y"]) > 0 and st["validation"]["X"].shape == (len(st["validation"]["y"]), 8)
