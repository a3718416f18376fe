"""Settings for every test run. Passive OpenMP waiting: spinning threads stall each other on 2 shared cores.
Under pytest-xdist (``-n auto`` in the default options) each worker runs Taichi, torch and OpenMP on one
thread, so that the workers share the cores instead of every worker's threads competing for all of them
(the CPU solver's results do not depend on its thread count: the shipped shard's bit-for-bit test runs so)."""

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
if os.environ.get("PYTEST_XDIST_WORKER"):
    for _var in ("TI_CPU_MAX_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")
