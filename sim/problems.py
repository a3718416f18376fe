"""Seeded sampler of planning problems: start cup pose, plant-pose jitter, goal amount."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .world import WorldConfig, check_world


@dataclass
class Problem:
    start: np.ndarray  # (5,) state: cup pose (x, y, 0), full cup, empty target
    plant_jitter: np.ndarray  # (3,) dx, dy (m), dtheta (rad) of the plant
    goal: float  # fraction of all water to end in the target cup
    world: str


def sample_problems(cfg: WorldConfig, n: int, seed: int, world: str = "target") -> list[Problem]:
    """``n`` problems from the configured distribution; the same seed gives the same problems."""
    check_world(world)
    if n < 1:
        raise ValueError(f"n = {n}: allowed an integer >= 1")
    rng = np.random.default_rng(seed)
    pr, pl = cfg.problems, cfg.plant
    out = []
    for _ in range(n):
        x = rng.uniform(*pr["start_x"])
        y = rng.uniform(*pr["start_y"])
        jit = np.array([rng.uniform(-1, 1) * pl["jitter_xy"], rng.uniform(-1, 1) * pl["jitter_xy"],
                        rng.uniform(-1, 1) * pl["jitter_tilt"]])
        if world == "source":
            jit[:] = 0.0
        out.append(Problem(start=np.array([x, y, 0.0, 1.0, 0.0]), plant_jitter=jit,
                           goal=float(rng.uniform(*pr["goal"])), world=world))
    return out
