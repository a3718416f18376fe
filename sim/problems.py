"""The task's problems (start cup pose, plant-pose jitter, goal amount): defined in :mod:`task.problems`.

Re-exported here for the simulator's callers: ``sample_problems(world_cfg, n, seed, world)`` draws from
the world's ``problems:`` block (``sim.world.WorldConfig.problems``) and its plant jitter.
"""

from __future__ import annotations

from task.problems import Problem, sample_problems

__all__ = ["Problem", "sample_problems"]
