"""The task's problems, defined once: a start state, a goal amount, the plant's pose jitter, a world.

One type (:class:`Problem`) and one seeded sampler (:func:`sample_problems`) driven by the world's
``problems:`` block (``configs/world/default.yaml``: start region, goal range) and its plant jitter;
the experiment, the planner's tools and the dynamics data all draw their problems here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

#: the two worlds: without the plant (the model's training world) and with it (the robot's world)
WORLDS = ("source", "target")


def check_world(world: str) -> None:
    if world not in WORLDS:
        raise ValueError(f"world = {world!r}: allowed one of {WORLDS}")


@dataclass
class Problem:
    """Start state ``(x, y, 0, 1, 0)`` (upright full cup, empty target), goal fraction ``g`` of all water
    to end in the target cup, the plant's pose jitter (dx, dy (m), dtheta (rad); zero in the source
    world) and the world it is posed in."""

    start: np.ndarray
    goal: float
    plant_jitter: np.ndarray = field(default_factory=lambda: np.zeros(3))
    world: str = "target"


def on_lattice(xy: Any, lattice: float) -> np.ndarray:
    """Positions rounded to the nearest multiple of ``lattice`` (m); 0 leaves them continuous.

    A world's ``skills.lattice`` puts every cup position (problem starts here, move targets in
    ``sim.skills.plan_schedule``) on the solver's grid phase, so a pouring lip always sits on the grid
    the same way: a world without the sub-cell term of a pour's scatter (std 0.017-0.026 over 32 offsets
    within one cell, a solver artefact no real cup has)."""
    xy = np.asarray(xy, float)
    return xy if not lattice else np.round(xy / lattice) * lattice


def _block(world_cfg: Any, name: str) -> Mapping[str, Any]:
    return world_cfg[name] if isinstance(world_cfg, Mapping) else getattr(world_cfg, name)


def draw_plant_jitter(plant: Any, rng: np.random.Generator) -> np.ndarray:
    """One plant-pose jitter (dx, dy (m), dtilt (rad)), uniform within the world's ``plant.jitter_xy`` /
    ``jitter_tilt``; three draws from ``rng`` in that order (the problems' random stream depends on it)."""
    return np.array(
        [
            rng.uniform(-1, 1) * plant["jitter_xy"],
            rng.uniform(-1, 1) * plant["jitter_xy"],
            rng.uniform(-1, 1) * plant["jitter_tilt"],
        ]
    )


def sample_problems(world_cfg: Any, n: int, seed: int | np.random.Generator, world: str = "target") -> list[Problem]:
    """``n`` problems from the world's ``problems:`` block; the same seed gives the same problems.

    ``world_cfg`` is the world config: a ``sim.world.WorldConfig`` or its mapping (``cfg["world"]``),
    read for ``problems.start_x / start_y / goal`` and ``plant.jitter_xy / jitter_tilt``. Per
    problem the draws are x, y, the three jitter values (drawn in the source world too, then zeroed,
    so both worlds get the same starts and goals for a seed) and the goal.
    """
    check_world(world)
    if n < 1:
        raise ValueError(f"n = {n}: allowed an integer >= 1")
    rng = np.random.default_rng(seed)
    pr, pl = _block(world_cfg, "problems"), _block(world_cfg, "plant")
    lattice = float(_block(world_cfg, "skills").get("lattice", 0.0))
    out = []
    for _ in range(n):
        x = rng.uniform(*pr["start_x"])
        y = rng.uniform(*pr["start_y"])
        jit = draw_plant_jitter(pl, rng)
        if world == "source":
            jit[:] = 0.0
        x, y = on_lattice((x, y), lattice)
        out.append(
            Problem(
                start=np.array([x, y, 0.0, 1.0, 0.0]),
                goal=float(rng.uniform(*pr["goal"])),
                plant_jitter=jit,
                world=world,
            )
        )
    return out
