"""Test doubles: hand-written stand-ins for the learned dynamics model, the MDE and simulator data.

Used by the tests and by ``benchmarks.planner``; never by product code. Nothing here is measured
from the simulator.
"""
