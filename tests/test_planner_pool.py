"""planner.pool: planning in worker processes gives exactly the in-process results, in request order.

One two-worker pool (spawned once for the module, ~5 s on 2 cores) serves most tests; the stand-in
dynamics model and small budgets keep each batch well under a second.
"""

from __future__ import annotations

import logging
import os
import pickle

import numpy as np
import pytest
import torch

from benchmarks.planner_pool import fingerprint
from planner import CandidateSet, Planner, PlannerConfig, PlanResult
from planner.pool import AUTO_MAX_WORKERS, PlanPool, PlanRequest, available_cpus, dumps, resolve_workers
from sim.world import WorldConfig
from task.problems import sample_problems
from tests.doubles.standins import StandInMLPDynamics, fitted_standin_mde, synthetic_deviation_dataset

CFG = PlannerConfig(propagation_budget=1500, time_budget=60.0, n_candidates=3)


@pytest.fixture(scope="module")
def dynamics():
    return StandInMLPDynamics(seed=0)


@pytest.fixture(scope="module")
def standin_mde():
    return fitted_standin_mde(150, seed=0, config=CFG)


@pytest.fixture(scope="module")
def real_mde():
    """The experiment's MDE class, fitted small (what the loop sends after every refit)."""
    from mde import GPMDE

    X, d = synthetic_deviation_dataset(40, np.random.default_rng(0), CFG)
    mde = GPMDE(fit_maxiter=30, max_iters=2).fit(torch.as_tensor(X), torch.as_tensor(d))
    assert mde.is_fitted
    return mde


@pytest.fixture(scope="module")
def pool(dynamics):
    with PlanPool(dynamics, CFG, workers=2, preload=["mde"]) as p:
        assert p.start() > 0 and p.parallel
        yield p
    assert not p.parallel


def requests() -> list[PlanRequest]:
    """Plans and candidate sets, mixed, with per-request seeds and precondition parameters."""
    probs = sample_problems(WorldConfig.load(), 5, np.random.default_rng(1))
    reqs = [PlanRequest("plan", p.start, p.goal, beta=2.0, d_max=0.07, seed=100 + i) for i, p in enumerate(probs)]
    reqs.insert(2, PlanRequest("candidates", probs[0].start, probs[0].goal, beta=-2.0, d_max=0.07, seed=7, n=3))
    reqs.append(PlanRequest("candidates", probs[3].start, probs[3].goal, beta=1.0, d_max=0.07, seed=8, n=2))
    return reqs


def in_process(dynamics, mde, reqs):
    """The reference: the Planner methods called directly, one after another."""
    planner = Planner(dynamics, mde, CFG)
    out = []
    for r in reqs:
        kw = dict(beta=r.beta, d_max=r.d_max, seed=r.seed)
        out.append(
            planner.plan(r.start, r.goal, **kw)
            if r.kind == "plan"
            else planner.plan_candidates(r.start, r.goal, n=r.n, **kw)
        )
    return out


@pytest.mark.parametrize("which", ["none", "standin", "real"])
def test_workers_give_the_in_process_results_bit_for_bit(pool, dynamics, standin_mde, real_mde, which):
    mde = {"none": None, "standin": standin_mde, "real": real_mde}[which]
    reqs = requests()
    want = in_process(dynamics, mde, reqs)
    got = pool.run(reqs, mde)
    assert pool.parallel  # no silent fallback
    assert [type(r) for r in got] == [type(r) for r in want]
    assert [fingerprint(r) for r in got] == [fingerprint(r) for r in want]
    assert any(r.found for r in want)  # the comparison covers found trajectories ...
    if which != "none":
        assert any(not r.found for r in want if isinstance(r, PlanResult))  # ... and the precondition at work
    for r in got:  # results come back read-only, as in-process
        for t in r.candidates if isinstance(r, CandidateSet) else [r.trajectory]:
            assert t is None or not t.actions.flags.writeable
    assert PlanPool(dynamics, CFG, workers=1).run(reqs, mde) and not PlanPool(dynamics, CFG, 0).parallel


def test_results_follow_request_order(pool, dynamics, standin_mde):
    reqs = requests()
    base = [fingerprint(r) for r in pool.run(reqs, standin_mde)]
    perm = [4, 0, 6, 2, 5, 1, 3]
    assert [fingerprint(r) for r in pool.run([reqs[i] for i in perm], standin_mde)] == [base[i] for i in perm]
    assert pool.run([], standin_mde) == []


def test_a_failing_request_raises_as_in_process_and_the_pool_goes_on(pool, dynamics):
    reqs = requests()
    bad = PlanRequest("plan", [0.4, 0.1, 0.0, 1.0, 0.0, 9.9], 0.5, seed=1)  # six state entries
    shape = r"start must be a state vector of 5 values .*got shape \(6,\)"
    with pytest.raises(ValueError, match=shape) as here:
        in_process(dynamics, None, [reqs[0], bad])
    with pytest.raises(ValueError, match=shape) as there:
        pool.run([reqs[0], bad, reqs[1]], None)
    assert str(there.value) == str(here.value)
    assert pool.parallel
    want = [fingerprint(r) for r in in_process(dynamics, None, reqs[:2])]
    assert [fingerprint(r) for r in pool.run(reqs[:2], None)] == want


@pytest.mark.parametrize("where", ["workers", "in_process"])
def test_recorded_errors_fail_only_their_own_runs(pool, dynamics, where):
    """errors="record": a run that raises is a run that found nothing, with the reason; the rest is unchanged."""
    reqs = requests()[:2]
    six = [0.4, 0.1, 0.0, 1.0, 0.0, 9.9]  # six state entries: the planner refuses them
    bad = [PlanRequest("plan", six, 0.5, seed=1), PlanRequest("candidates", six, 0.5, seed=2, n=2)]
    runner = pool if where == "workers" else PlanPool(dynamics, CFG, workers=1)
    got = runner.run([reqs[0], bad[0], reqs[1], bad[1]], None, errors="record")
    want = in_process(dynamics, None, reqs)
    assert [fingerprint(got[0]), fingerprint(got[2])] == [fingerprint(r) for r in want]
    assert isinstance(got[1], PlanResult) and not got[1].found
    assert got[1].stats.termination == "error" and got[1].stats.error.startswith("ValueError")
    assert isinstance(got[3], CandidateSet) and not got[3].found and len(got[3].runs) == 2
    assert all(r.stats.termination == "error" for r in got[3].runs)
    with pytest.raises(ValueError, match=r"errors = 'ignore': allowed one of \('raise', 'record'\)"):
        runner.run(reqs, None, errors="ignore")


class DiesInWorkers:
    """An MDE that kills any process but the one that made it (a worker crash, e.g. out of memory)."""

    def __init__(self, mde):
        self.mde, self.parent = mde, os.getpid()

    def predict(self, X):
        if os.getpid() != self.parent:
            os._exit(3)
        return self.mde.predict(X)


def test_a_dead_worker_falls_back_to_in_process_with_the_same_results(dynamics, standin_mde, caplog):
    reqs = requests()[:4]
    mde = DiesInWorkers(standin_mde)
    want = [fingerprint(r) for r in in_process(dynamics, mde, reqs)]
    with caplog.at_level(logging.WARNING, logger="planner.pool"), PlanPool(dynamics, CFG, workers=2) as p:
        got = [fingerprint(r) for r in p.run(reqs, mde)]
        assert not p.parallel and "worker process died" in p.fallback_reason
        again = [fingerprint(r) for r in p.run(reqs, standin_mde)]  # later batches: in-process
    assert got == want
    assert again == [fingerprint(r) for r in in_process(dynamics, standin_mde, reqs)]
    assert "planning in the main process from now on" in caplog.text


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "many", None, "2"])
def test_bad_workers_value_is_refused_naming_the_field(bad):
    with pytest.raises(ValueError, match=r"^planner\.workers = .*: allowed an integer >= 1 .* or 'auto'"):
        resolve_workers(bad)


def test_workers_values():
    assert resolve_workers("auto") == max(1, min(available_cpus(), AUTO_MAX_WORKERS))
    assert resolve_workers(3) == 3 and resolve_workers(np.int64(1)) == 1


def test_workers_key_is_validated_before_compute_and_left_out_of_the_digest(tmp_path):
    from active.identity import config_digest
    from active.planner_setup import build_planner_config, planner_workers
    from active.run import compose_config, run_experiment

    cfg = compose_config(
        [
            "experiment=tiny",
            "wandb.mode=disabled",
            "progress=false",
            "planner.workers=0",
            f"dynamics.cache_root={tmp_path / 'cache'}",
        ]
    )
    with pytest.raises(ValueError, match=r"^planner\.workers = 0: allowed"):
        run_experiment(cfg, tmp_path / "out")
    assert not (tmp_path / "out").exists() and not (tmp_path / "cache").exists()
    ok = compose_config(["experiment=tiny", "planner.workers=2"])
    assert planner_workers(ok["planner"]) == 2
    assert config_digest(ok) == config_digest(compose_config(["experiment=tiny", "planner.workers=auto"]))
    default = compose_config(["experiment=tiny"])
    assert default["planner"]["workers"] == "auto"
    without = {**default, "planner": {k: v for k, v in default["planner"].items() if k != "workers"}}
    assert config_digest(without) == config_digest(default)  # where plans are computed is not what they are
    from active.experiment import ExperimentConfig
    from sim.world import WorldConfig

    world, exp = WorldConfig.from_mapping(ok["world"]), ExperimentConfig.from_mapping(ok["experiment"])
    pc = build_planner_config(world, ok["planner"], exp)
    assert not hasattr(pc, "workers")


def test_contact_aware_dynamics_reaches_workers_intact():
    """Its forwarding __getattr__ must not recurse when the plain unpickler rebuilds it."""
    from dynamics import ContactAwareDynamics
    from sim.world import WorldConfig

    dyn = ContactAwareDynamics(StandInMLPDynamics(seed=0), WorldConfig.load())
    copy = pickle.loads(dumps(dyn))
    assert isinstance(pickle.loads(pickle.dumps(dyn)), ContactAwareDynamics)
    s = torch.tensor([[0.4, 0.1, 0.0, 1.0, 0.0]] * 3, dtype=torch.float32)
    a = torch.tensor([[0.0, 0.1, 0.2], [1.0, 1.5, 0.5], [0.0, 0.5, 0.05]], dtype=torch.float32)
    assert torch.equal(copy.predict(s, a), dyn.predict(s, a))


def test_an_mde_that_does_not_pickle_is_planned_in_process(dynamics, standin_mde, tmp_path):
    """Nothing is submitted, the pool falls back with the reason, and the results are the in-process ones."""
    import threading

    class Unpicklable:
        dtype = torch.float64

        def __init__(self):
            self.lock = threading.Lock()  # locks do not pickle

        def predict(self, X):
            return standin_mde.predict(X)

    class NoSubmit:  # stands in for started workers
        _processes: dict = {}

        def submit(self, *a, **kw):
            raise AssertionError("nothing may reach the workers")

        def shutdown(self, wait, cancel_futures):
            pass

    reqs = requests()[:3]
    mde = Unpicklable()
    with PlanPool(dynamics, CFG, workers=2) as p:
        p._executor, p._tmp = NoSubmit(), tmp_path / "tmp"
        got = p.run(reqs, mde)
        assert not p.parallel and "MDE could not be sent" in p.fallback_reason
    assert [fingerprint(r) for r in got] == [fingerprint(r) for r in in_process(dynamics, mde, reqs)]


def test_runs_stopped_by_the_wall_clock_budget_are_reported(dynamics, caplog):
    """A run that ends on the wall-clock safety net instead of the propagation budget depends on the machine's
    speed at that moment: the pool says so (a suspended run would otherwise differ from its rerun silently)."""
    import dataclasses

    cfg = dataclasses.replace(CFG, time_budget=1e-9, propagation_budget=10**6)
    reqs = requests()[:3]
    with caplog.at_level(logging.WARNING, logger="planner.pool"):
        out = PlanPool(dynamics, cfg, workers=1).run(reqs)
    runs = [r for res in out for r in (res.runs if isinstance(res, CandidateSet) else [res])]
    assert runs and all(r.stats.termination == "time_budget" for r in runs)
    msg = [r.getMessage() for r in caplog.records if "wall-clock time budget" in r.getMessage()]
    assert msg and f"{len(runs)} of {len(runs)} run(s)" in msg[0]
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="planner.pool"):
        PlanPool(dynamics, CFG, workers=1).run(reqs[:1])
    assert not any("wall-clock" in r.getMessage() for r in caplog.records)
