"""Learned dynamics model f_hat(s, a) of the pouring task, trained on the source world only.

The paper's inaccurate model: an MLP per skill trained on cheap source-world (no plant) simulator
data, used by the planner in the target world, where it is wrong near the plant. By default the
mean of three such models (``model.ensemble``, :class:`DynamicsEnsemble`): a planner searching one
model finds its idiosyncratic errors.

    from dynamics import load_or_train
    model = load_or_train(cfg.dynamics, world_cfg=cfg.world)  # cached by config hash; shipped or trained if missing
    s_next = model.predict(states, actions)                # torch [n, 5], [n, 3] -> [n, 5] float32
    s1 = model.predict_one(s, a)                           # numpy fast path for one transition

Commands: ``python -m dynamics.train`` (Hydra, ``configs/dynamics``), ``python -m dynamics.evaluate
--out DIR``, ``python -m dynamics.shipped`` (the default's data and members, shipped with the package:
:mod:`dynamics.shipped`) and ``python -m benchmarks.dynamics``. Depends on ``sim`` (data generation) only.
"""

import importlib

from .config import (
    DataConfig,
    DynamicsConfig,
    DynamicsError,
    EvalConfig,
    ModelConfig,
    TrainConfig,
    data_hash,
    model_hash,
)
from .data import Transitions, generate_source_dataset, generate_transitions
from .model import LearnedDynamics

# imported lazily so that `python -m dynamics.train` does not find its own module pre-imported
_LAZY = {
    "ContactAwareDynamics": "contact",
    "DynamicsEnsemble": "ensemble",
    "cache_paths": "train",
    "error_table": "train",
    "fit": "train",
    "load_or_generate_dataset": "train",
    "load_or_train": "train",
}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module 'dynamics' has no attribute {name!r}")


__all__ = [
    "ContactAwareDynamics",
    "DataConfig",
    "DynamicsConfig",
    "DynamicsEnsemble",
    "DynamicsError",
    "EvalConfig",
    "LearnedDynamics",
    "ModelConfig",
    "TrainConfig",
    "Transitions",
    "cache_paths",
    "data_hash",
    "error_table",
    "fit",
    "generate_source_dataset",
    "generate_transitions",
    "load_or_generate_dataset",
    "load_or_train",
    "model_hash",
]
