"""The MDE's calibration on held-out target-world transitions, and the held-out set itself.

Every method of a seed is scored on the same held-out transitions (random actions in the target
world, made once per seed and saved in the run directory as ``calibration_set.pt``, tagged with the
digest of the configuration that made it): the coverage of the MDE's intervals and its NLL, per
iteration, in ``calibration.csv``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch

from mde.calibration import fitted_labels, gaussian_calibration
from planner import ActionSampler, features
from sim.execute import PouringExecutor
from sim.world import WorldConfig
from task.problems import sample_problems

from .identity import RUN_FORMAT_VERSION, config_differences, config_digest
from .io import RunFileError, as_json, load_checked, save_checked
from .labels import label_transitions, stack_steps
from .seeds import derive_seed

log = logging.getLogger(__name__)

CALIBRATION_FORMAT = "active-mde/calibration-set"
CALIBRATION_FIELDS = [
    "method",
    "seed",
    "iteration",
    "n",
    "coverage50",
    "coverage80",
    "coverage95",
    "nll",
    "coverage95_raw",
    "nll_raw",
]


def make_calibration_set(
    world: WorldConfig, dynamics: Any, executor: PouringExecutor, sampler: ActionSampler, n: int, length: int, seed: int
) -> dict:
    """Held-out target-world transitions from random actions (the same for every method of a seed)."""
    problems = sample_problems(world, n, derive_seed(seed, "calibration"), world="target")
    rng = np.random.default_rng(derive_seed(seed, "calibration-actions"))
    acts = [sampler.sample(length, rng) for _ in problems]
    res = executor.run(
        "target",
        np.array([p.start[:3] for p in problems]),
        acts,
        plant_jitter=np.array([p.plant_jitter for p in problems]),
    )
    s, a, s2 = stack_steps(res)
    y = label_transitions(dynamics, s, a, s2, world.distance_weights)
    return {"X": torch.as_tensor(features(s, a)), "y": torch.as_tensor(y)}


def calibration_row(mde: Any, X: Any, y: Any, method: str, seed: int, iteration: int) -> dict:
    """One row of ``calibration.csv``: the MDE's interval coverage and NLL on the held-out transitions, against
    the labels as the MDE fits them (capped at ``mde.label_max``: a raw label above the cap lies outside every
    interval by construction), and the 95 % coverage and NLL against the raw labels beside them."""
    mean, std = mde.predict(torch.as_tensor(X))  # once, for both comparisons
    rep = gaussian_calibration(mean, std, fitted_labels(mde, y))
    raw = gaussian_calibration(mean, std, torch.as_tensor(y), levels=(0.95,))
    cov = {float(k): float(v) for k, v in rep["coverage"].items()}
    return {
        "method": method,
        "seed": seed,
        "iteration": iteration,
        "n": int(rep["n"]),
        "coverage50": cov.get(0.5),
        "coverage80": cov.get(0.8),
        "coverage95": cov.get(0.95),
        "nll": float(rep["nll"]),
        "coverage95_raw": float(raw["coverage"]["0.95"]),
        "nll_raw": float(raw["nll"]),
    }


def load_calibration(path: Path, cfg: Mapping[str, Any]) -> dict | None:
    """The directory's held-out calibration set if ``cfg`` made it, else None (it must be rebuilt).

    Read before any compute. The file records the digest of the configuration that made it; a set made by
    another configuration or run format (e.g. a run of another seed killed before its first iteration) is
    not reused (warned): the set is a deterministic function of the configuration. A damaged file is an
    error naming it and the fix.
    """
    if not path.exists():
        return None
    fix = (
        f"delete it and run the same command again: it is rebuilt from the configuration (the same set for the "
        f"same configuration); results, checkpoints and datasets in {path.parent} are kept"
    )
    data = load_checked(path, fix=fix)
    if not (isinstance(data, dict) and data.get("format") == CALIBRATION_FORMAT and "X" in data and "y" in data):
        raise RunFileError(f"{path} is not a calibration set of this runner; {fix}")
    if data.get("version") == RUN_FORMAT_VERSION and data.get("digest") == config_digest(cfg):
        return {"X": data["X"], "y": data["y"]}
    diffs = config_differences(data.get("config"), cfg)
    log.warning(
        "%s was made by another configuration or run format (%s); rebuilding it",
        path,
        "; ".join(diffs) or f"format version {data.get('version')}, digest {data.get('digest')}",
    )
    return None


def save_calibration(path: Path, cal: Mapping[str, Any], cfg: Mapping[str, Any]) -> dict:
    """Write the calibration set tagged with the configuration that made it; returns its X and y."""
    save_checked(
        path,
        {
            "format": CALIBRATION_FORMAT,
            "version": RUN_FORMAT_VERSION,
            "digest": config_digest(cfg),
            "config": as_json(cfg),
            "X": cal["X"],
            "y": cal["y"],
        },
    )
    return {"X": cal["X"], "y": cal["y"]}
