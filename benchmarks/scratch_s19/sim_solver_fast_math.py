"""Scratch (session 19): benchmarks.sim_solver with Taichi's fast math forced back on (the solver's CPU
default is off since session 19), for an A/B against the default in alternating processes.
usage (repository root): PYTHONPATH=. python benchmarks/scratch_s19/sim_solver_fast_math.py --out X.json --envs 32 --seconds 4"""
import runpy
import sys

import taichi as ti

_init = ti.init


def init(*a, **k):
    k["fast_math"] = True
    return _init(*a, **k)


ti.init = init
sys.argv = ["sim_solver"] + sys.argv[1:]
runpy.run_module("benchmarks.sim_solver", run_name="__main__")
