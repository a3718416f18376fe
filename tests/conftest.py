"""Settings for every test run. Passive OpenMP waiting: spinning threads stall each other on 2 shared cores.
Under pytest-xdist (``-n auto`` in the default options) each worker runs Taichi, torch and OpenMP on one
thread, so that the workers share the cores instead of every worker's threads competing for all of them
(the CPU solver's results do not depend on its thread count: the shipped shard's bit-for-bit test runs so)."""

import os

import pytest

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
if os.environ.get("PYTEST_XDIST_WORKER"):
    for _var in ("TI_CPU_MAX_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")


@pytest.fixture(scope="session")
def shared_solver():
    """``shared_solver(**sim_fields)``: one ``MPMSolver`` per configuration and test process, built on first use
    and shared by every test that asks for the same fields; a test ``reset``s it before use and never closes it.

    Taichi compiles a solver's kernels for each solver object: a second solver of an identical configuration in
    the same process compiles them again (the CPU path's substep kernel took 53-63 s on this 2-core machine under
    load, against well under a second to run the small scenes here), so tests that share one compile it once.
    ``tests/test_sim_solver.py`` checks that a reset solver reproduces a fresh one bit for bit."""
    from sim.engine.config import SimConfig
    from sim.engine.mpm import MPMSolver

    built: dict = {}

    def get(**fields):
        cfg = SimConfig(**fields)
        key = tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in cfg.to_dict().items()))
        if key not in built:
            built[key] = MPMSolver(cfg)
        return built[key]

    yield get
    for solver in built.values():
        solver.close()
