"""OMPL kinodynamic RRT planner with a learned dynamics model and an MDE model precondition.

Public API: :class:`Planner` (``plan`` / ``plan_candidates``), :class:`PlannerConfig`,
:class:`ActionSampler` and :func:`rollout` (shared with the Random Actions baseline), the result
dataclasses and the interface helpers in :mod:`planner.interfaces`. Stand-in models for tests live in
``tests/doubles/standins.py``; ``python -m benchmarks.planner`` measures planning speed.
"""

from .config import PlannerConfig
from .interfaces import (
    ACTION_DIM,
    FEATURE_DIM,
    SKILL_MOVE,
    SKILL_POUR,
    STATE_DIM,
    DeviationEstimator,
    DynamicsModel,
    features,
    goal_distance,
    goal_reached,
    spill,
)
from .results import CandidateSet, PlannerStats, PlanResult, Trajectory
from .rollout import rollout
from .rrt import Planner
from .sampling import ActionSampler

__all__ = [
    "ACTION_DIM",
    "FEATURE_DIM",
    "SKILL_MOVE",
    "SKILL_POUR",
    "STATE_DIM",
    "ActionSampler",
    "CandidateSet",
    "DeviationEstimator",
    "DynamicsModel",
    "PlanResult",
    "Planner",
    "PlannerConfig",
    "PlannerStats",
    "Trajectory",
    "features",
    "goal_distance",
    "goal_reached",
    "rollout",
    "spill",
]
