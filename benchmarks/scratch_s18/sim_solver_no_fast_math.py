"""Scratch (session 18): benchmarks.sim_solver with Taichi built without fast math (ti.init(fast_math=False)).
usage (repository root): PYTHONPATH=. python benchmarks/scratch_s18/sim_solver_no_fast_math.py --out X.json --envs 32 --seconds 4"""
import sys, taichi as ti
_init = ti.init
def init(*a, **k):
    k.setdefault("fast_math", False)
    return _init(*a, **k)
ti.init = init
import runpy
sys.argv = ["sim_solver"] + sys.argv[1:]
runpy.run_module("benchmarks.sim_solver", run_name="__main__")
