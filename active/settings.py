"""The run config read once into the typed objects the code works with.

Why: a composed config is a tree of plain values; each consumer used to rebuild its part (``WorldConfig.from_mapping``
here, ``DynamicsConfig.from_dict`` there), so one value was parsed and checked in several places. :func:`read_settings`
builds every part once, after ``configs.schema.check_config`` has checked each leaf, and the code passes the typed
objects on (the dynamics cache, the planner, the loop, the ladder, the benchmarks).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from dynamics import DynamicsConfig
from planner import PlannerConfig
from sim.world import WorldConfig

from .experiment import ExperimentConfig
from .planner_setup import build_planner_config, planner_workers
from .preflight import check_geometry


@dataclass(frozen=True)
class Settings:
    """What a run of a config is set to: experiment, world (checked against its geometry), dynamics model, the
    planner config every planning call gets, and how many planner processes serve them."""

    exp: ExperimentConfig
    world: WorldConfig
    dynamics: DynamicsConfig
    planner: PlannerConfig
    workers: int


def read_settings(cfg: Mapping[str, Any], method: str | None = None) -> Settings:
    """The typed :class:`Settings` of a composed run config (errors name the key and what is allowed); ``method``
    replaces the config's ``method`` (``"all"``: every method of the experiment, as the tools that plan for a run
    want)."""
    method = str(cfg.get("method", "all")) if method is None else method
    exp = ExperimentConfig.from_mapping(cfg["experiment"], method=method, registry=cfg.get("methods"))
    world = WorldConfig.from_mapping(cfg["world"])
    check_geometry(world)
    return Settings(
        exp=exp,
        world=world,
        dynamics=DynamicsConfig.from_dict(cfg["dynamics"]),
        planner=build_planner_config(world, cfg["planner"], exp),
        workers=planner_workers(cfg["planner"]),
    )
