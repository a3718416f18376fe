"""Checks that must pass before a run computes anything (no data generation, training, simulation).

Why: a run that fails after generating data and training a model (or after a whole iteration)
wastes that compute and may leave a degenerate cached model behind. Every message names the field
and what is allowed.
"""

from __future__ import annotations

import itertools
import os
import secrets
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from dynamics.config import DynamicsConfig
from dynamics.train import cache_paths, is_cached
from sim.skills import Obstacles, cup_boundary, to_world
from sim.world import WorldConfig

from .runlock import RunDirectoryError

#: seeds feed numpy's SeedSequence (non-negative) and torch.manual_seed; 32 bits fit both everywhere
MAX_SEED = 2**32 - 1
#: cup walls thinner than this many grid cells leak water (README: "walls two cells thick do not leak")
MIN_WALL_CELLS = 2


def check_seed(value: Any, name: str = "seed") -> int:
    """``value`` as a seed, or a ValueError naming ``name`` and the allowed range."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= int(value) <= MAX_SEED:
        raise ValueError(f"{name} = {value!r}: allowed an integer in [0, {MAX_SEED}]")
    return int(value)


def max_dx(world: Any) -> tuple[float, dict[str, float]]:
    """The coarsest grid spacing the world's geometry allows, and the limit of each constraint.

    * ``cup_walls``: every cup wall at least :data:`MIN_WALL_CELLS` cells thick;
    * ``tank``: the controlled cup at every problem start pose inside the tank interior, whose
      walls are ``sim.wall_cells`` cells thick (so they grow with dx).
    """
    wall_cells = world.sim_config(1).wall_cells
    limits = {"cup_walls": min(world.controlled_cup.wall, world.target_cup.wall) / MIN_WALL_CELLS}
    pts = to_world(cup_boundary(world, spacing=0.002), _start_poses(world)).reshape(-1, 2)
    domain = np.asarray(world.sim["domain"], float)[:2]
    clearance = float(min(pts.min(), (domain - pts).min()))  # from the tank's outer edge
    limits["tank"] = max(clearance, 0.0) / wall_cells
    return min(limits.values()), limits


def check_geometry(world: Any) -> None:
    """Refuse a resolution too coarse for the geometry, or start poses that overlap an obstacle.

    Same tests the executor makes when it starts a trajectory (``sim.execute``: the cup outline
    against the tank interior and the bodies), made here on the whole start range before compute.
    """
    sc = world.sim_config(1)
    dx, wall_cells = float(sc.dx), sc.wall_cells
    limit, limits = max_dx(world)
    if dx > limit * (1 + 1e-9):
        why = []
        if dx > limits["cup_walls"] * (1 + 1e-9):
            cc, tc = world.controlled_cup, world.target_cup
            why.append(
                f"the cup walls (controlled_cup.wall = {cc.wall:g} m, target_cup.wall = {tc.wall:g} m) must be "
                f"at least {MIN_WALL_CELLS} cells thick or water leaks through them"
            )
        if dx > limits["tank"] * (1 + 1e-9):
            why.append(
                f"the tank walls ({wall_cells} cells = {wall_cells * dx:g} m thick) would overlap the "
                f"controlled cup at the problem start poses (problems.start_x / start_y)"
            )
        raise ValueError(
            f"world.sim.dx = {dx:g}: too coarse for the geometry: {'; and '.join(why)}. Allowed: "
            f"0 < dx <= {limit:g} m (with world.sim.wall_cells = {wall_cells}), e.g. the default 0.01 "
            f"or world=fine (0.005)"
        )
    lo = np.full(2, world.floor)
    hi = np.asarray(world.sim["domain"], float)[:2] - world.floor
    boundary = cup_boundary(world, spacing=0.002)
    pl = world.plant
    jxy, jt = float(pl.get("jitter_xy", 0.0)), float(pl.get("jitter_tilt", 0.0))
    for jit in itertools.product((-jxy, 0.0, jxy), (-jxy, 0.0, jxy), (-jt, 0.0, jt)):
        obst = Obstacles(world.obstacle_bodies("target", np.array(jit)), lo, hi)
        for pose in _start_poses(world):
            d, idx = obst.sdf(to_world(boundary, pose[None])[0])
            if d.min() < 0:
                who = int(idx[np.argmin(d)])
                name = "tank wall" if who < 0 else f"{obst.bodies[who].name} body"
                pr = world.problems
                raise ValueError(
                    f"world.problems.start_x = {list(pr['start_x'])}, start_y = {list(pr['start_y'])}: "
                    f"the controlled cup at the start pose ({pose[0]:g}, {pose[1]:g}) overlaps the "
                    f"{name}; allowed: start ranges that keep the cup clear of the tank walls, the target "
                    f"cup and the plant"
                )


def _start_poses(world: Any, n: int = 5) -> np.ndarray:
    """Upright cup poses on an n x n grid over the problems' start range (its corners included)."""
    pr = world.problems
    xs, ys = np.linspace(*pr["start_x"], n), np.linspace(*pr["start_y"], n)
    return np.array([(x, y, 0.0) for x in xs for y in ys])


def check_writable(folders: Iterable[Path], what: str = "output directory", field: str = "hydra.run.dir") -> None:
    """Create each folder and write (and remove) a probe file in it, or raise naming the folder.

    A probe rather than ``os.access``: it also catches read-only mounts, ACLs and a file standing
    where the folder should be (and ``os.access`` says yes to root everywhere).
    """
    for d in folders:
        d = Path(d)
        # a hidden .tmp name: a probe left by a killed run is removed with the other leftovers
        probe = d / f".write-probe.{os.getpid()}.{secrets.token_hex(4)}.tmp"
        try:
            d.mkdir(parents=True, exist_ok=True)
            os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            try:
                os.unlink(probe)
            except FileNotFoundError:  # the directory's owner cleaned it up as a leftover meanwhile
                pass
        except OSError as e:
            msg = (
                f"{what} {d} is not writable ({e.strerror or type(e).__name__}"
                f"{': a file is in the way' if d.exists() and not d.is_dir() else ''}); fix its permissions or "
                f"choose another location ({field}=...)"
            )
            if field == "hydra.run.dir":
                raise RunDirectoryError(msg) from None
            raise ValueError(msg) from None


def check_dynamics(c: DynamicsConfig, world: WorldConfig) -> dict[str, Any]:
    """If the model of ``c`` (in ``world``'s source world) is not all in the cache yet, the cache must be writable
    (a complete cache may be read-only).

    Returns :func:`dynamics.train.cache_paths` (where the data and the model are / will be).
    """
    p = cache_paths(c, None, world)
    if not is_cached(c, None, world):
        check_writable([p["root"]], what="dynamics cache", field="dynamics.cache_root")
    return p
