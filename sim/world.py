"""The pouring worlds: geometry and limits from ``configs/world``, scenes per problem, the state.

Source world: the controlled cup (full, upright) and the target cup on the floor. Target world: the
same plus a plant (stem and leaves) left of the target cup whose leaves overhang the left part of its
mouth. State s = (x, y, theta, v_ctrl, v_tgt): the pose of the controlled cup's inner-floor centre
and the fractions of all water inside the controlled and the target cup ("inside" = the cup's
interior box, floor to rim, in the cup's own frame, with half a cell of tolerance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

import configs
from task import STATE_DIM, WORLDS, check_world, goal_reached, spill, state_distance  # noqa: F401 - the task's one home, re-exported

from .engine.config import ConfigError, SimConfig
from .engine.scene import Body, EnvSpec, Shape, WaterBlock, open_box

DEFAULT_CONFIG = configs.path("world", "default.yaml")
CTRL, TARGET, PLANT = 0, 1, 2  # body indices in every environment


@dataclass
class CupConfig:
    inner_width: float
    inner_height: float
    wall: float
    fill_height: float = 0.0
    x: float = 0.0

    def shapes(self) -> list[Shape]:
        return open_box(self.inner_width, self.inner_height, self.wall)

    @property
    def lip(self) -> np.ndarray:
        """Pouring lip (outer top corner of the left wall) in the cup frame."""
        return np.array([-self.inner_width / 2 - self.wall, self.inner_height])


#: allowed values of ``world.plant.on_contact``
PLANT_CONTACT = ("stop", "hold", "stuck")


@dataclass
class WorldConfig:
    """Everything about the worlds, with units; built from ``configs/world/default.yaml``."""

    sim: dict
    control_dt: float
    controlled_cup: CupConfig
    target_cup: CupConfig
    plant: dict
    skills: dict
    problems: dict
    distance_weights: dict = field(default_factory=lambda: {"pose": 1.0, "volume": 1.0})

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "WorldConfig":
        data = dict(data)
        try:
            data["controlled_cup"] = CupConfig(**data["controlled_cup"])
            data["target_cup"] = CupConfig(**data["target_cup"])
            cfg = cls(**data)
        except TypeError as e:
            raise ConfigError(f"world config: {e}") from None
        cfg.validate()
        return cfg

    @classmethod
    def load(cls, path: str | Path | None = None, **overrides: Any) -> "WorldConfig":
        data = yaml.safe_load(Path(path or DEFAULT_CONFIG).read_text())
        data.update(overrides)
        return cls.from_mapping(data)

    def sim_config(self, n_envs: int, **overrides: Any) -> SimConfig:
        return SimConfig.from_mapping(self.sim, n_envs=n_envs, **overrides)

    def validate(self) -> None:
        sc = self.sim_config(1)
        if self.control_dt < sc.dt:
            raise ConfigError(f"world.control_dt = {self.control_dt} must be >= sim.dt = {sc.dt}")
        for name, rng in (
            ("skills.move.x", self.skills["move"]["x"]),
            ("skills.move.y", self.skills["move"]["y"]),
            ("skills.pour.theta", self.skills["pour"]["theta"]),
            ("skills.pour.hold", self.skills["pour"]["hold"]),
            ("problems.goal", self.problems["goal"]),
        ):
            if len(rng) != 2 or not rng[0] <= rng[1]:
                raise ConfigError(f"world.{name} = {rng}: allowed a [low, high] pair with low <= high")
        g0, g1 = self.problems["goal"]
        if not 0 <= g0 <= g1 <= 1:
            raise ConfigError(f"world.problems.goal = {[g0, g1]}: allowed a sub-range of [0, 1]")
        lat = self.skills.get("lattice", 0.0)
        if not (isinstance(lat, (int, float)) and 0 <= lat <= 0.05):
            raise ConfigError(
                f"world.skills.lattice = {lat!r}: allowed 0 (continuous positions) or a spacing in (0, 0.05] m"
            )
        if self.plant_on_contact not in PLANT_CONTACT:
            raise ConfigError(f"world.plant.on_contact = {self.plant_on_contact!r}: allowed {', '.join(PLANT_CONTACT)}")
        if not 1 <= int(self.skills["max_actions"]) <= 6:
            raise ConfigError(f"world.skills.max_actions = {self.skills['max_actions']}: allowed 1..6")

    @property
    def plant_on_contact(self) -> str:
        """What a cup blocked by the plant does: "stop" ends the trajectory there, "hold" keeps the cup at
        the leaf for the rest of that action and goes on with the next (see :func:`sim.skills.plan_schedule`),
        "stuck" ends it as "stop" does and records every action left as attempted without effect (s' = s; see
        :meth:`sim.execute.PouringExecutor.run`)."""
        return self.plant.get("on_contact", "stop")

    # ------------------------------------------------------------------ geometry
    @property
    def floor(self) -> float:
        return self.sim_config(1).wall

    def target_pose(self) -> tuple[float, float, float]:
        tc = self.target_cup
        return (tc.x, self.floor + tc.wall, 0.0)

    def plant_pose(self, jitter: np.ndarray | None = None) -> tuple[float, float, float]:
        j = np.zeros(3) if jitter is None else np.asarray(jitter, float)
        return (self.plant["stem_x"] + j[0], self.floor + j[1], j[2])

    def plant_shapes(self) -> list[Shape]:
        h, r = self.plant["stem_height"], self.plant["stem_radius"]
        shapes = [Shape("capsule", center=(0.0, h / 2), angle=math.pi / 2, size=(h / 2, r))]
        for leaf in self.plant["leaves"]:
            shapes.append(
                Shape("ellipse", center=tuple(leaf["center"]), angle=float(leaf["angle"]), size=tuple(leaf["radii"]))
            )
        return shapes

    def obstacle_bodies(self, world: str, plant_jitter: np.ndarray | None = None) -> list[Body]:
        check_world(world)
        bodies = [Body("target", pose=self.target_pose(), shapes=self.target_cup.shapes())]
        if world == "target":
            bodies.append(Body("plant", pose=self.plant_pose(plant_jitter), shapes=self.plant_shapes()))
        return bodies

    def scene(
        self,
        world: str,
        cup_pose: tuple[float, float, float],
        plant_jitter: np.ndarray | None = None,
        full: bool = True,
    ) -> EnvSpec:
        """The environment for one problem: controlled cup (full) at ``cup_pose`` plus obstacles."""
        cc = self.controlled_cup
        cup = Body("cup", pose=tuple(float(v) for v in cup_pose), shapes=cc.shapes())
        water = [WaterBlock((-cc.inner_width / 2, 0.0), (cc.inner_width / 2, cc.fill_height), body="cup")]
        water = water if full else []
        return EnvSpec(bodies=[cup] + self.obstacle_bodies(world, plant_jitter), water=water)

    def volume_regions(self) -> tuple[list[int], np.ndarray, np.ndarray]:
        """Interior boxes of the controlled and the target cup, each in its own frame."""
        tol = 0.5 * float(self.sim["dx"])
        lo, hi = [], []
        for cup in (self.controlled_cup, self.target_cup):
            lo.append([-cup.inner_width / 2 - tol, -tol])
            hi.append([cup.inner_width / 2 + tol, cup.inner_height + tol])
        return [CTRL, TARGET], np.array(lo), np.array(hi)
