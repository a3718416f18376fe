"""Session 44: what a fresh solver costs before it simulates (why the test suite's time is mostly Taichi compiles).

    PYTHONPATH=.:tests python benchmarks/scratch_s44/compile_cost.py [N]

Builds N (default 6) two-environment solvers of the tests' size one after another in one process, each reset with two
cups and advanced 0.1 s twice, and prints the seconds of each part. The first advance of a solver compiles its kernels,
or loads them from Taichi's offline cache (~/.cache/taichi), whose entries are per field tree, so the k-th solver of a
process hits the cache only if some earlier process built k solvers too; the second advance is the simulation itself.
Session 44 (a fresh machine): cached ~2 s, not cached 24 s, simulating 0.1 s 0.01 s.
"""
import sys
import time

from sim.config import SimConfig
from sim.mpm import MPMSolver
from test_sim_solver import _cup_env

for i in range(int(sys.argv[1]) if len(sys.argv) > 1 else 6):
    t0 = time.perf_counter()
    solver = MPMSolver(SimConfig(n_envs=2, max_particles=512))
    t1 = time.perf_counter()
    solver.reset([_cup_env(), _cup_env(x=0.25)])
    t2 = time.perf_counter()
    solver.advance(0.1)
    t3 = time.perf_counter()
    solver.advance(0.1)
    t4 = time.perf_counter()
    solver.close()
    print(f"solver {i}: build {t1 - t0:.2f} s, reset {t2 - t1:.2f} s, first 0.1 s (compile or cache) {t3 - t2:.2f} s, "
          f"next 0.1 s {t4 - t3:.2f} s", flush=True)
