"""A known, hand-written pouring-like transition function and datasets drawn from it.

For tests and for trying the training pipeline without the simulator: the network must recover
this function, and the cache logic can be exercised with :func:`synthetic_generator` in place of
the (minutes-long) simulator generator. Nothing here is measured from the simulator.

move(x, y): the cup goes to (x, y), except that a target inside a "block" (x < 0.30, y < 0.12, a
stand-in for the target cup) stops it on the block's top (y = 0.12). pour(theta, hold): the cup
keeps at most ``1 - 0.6 theta`` of its volume; a hold-dependent share of the excess leaves, and
the share of that landing in the target cup is a smooth window of the cup's x position.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from dynamics.data import MOVE, POUR, Transitions

BLOCK_X, BLOCK_TOP = 0.30, 0.12


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


def analytic_step(s: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Next states (n, 5) for states (n, 5) and actions (n, 3) of the synthetic world."""
    s, a = np.atleast_2d(np.asarray(s, float)), np.atleast_2d(np.asarray(a, float))
    out = s.copy()
    mv = np.rint(a[:, 0]) == MOVE
    x, y = a[:, 1], a[:, 2]
    blocked = (x < BLOCK_X) & (y < BLOCK_TOP)
    out[mv, 0] = x[mv]
    out[mv, 1] = np.where(blocked, BLOCK_TOP, y)[mv]
    pr = ~mv
    theta, hold = a[:, 1], a[:, 2]
    vc, vt = s[:, 3], s[:, 4]
    capacity = np.clip(1.0 - 0.6 * theta, 0.0, 1.0)
    leaving = np.maximum(vc - capacity, 0.0) * (1.0 - np.exp(-(hold + 0.2) / 0.3))
    into = _sigmoid((s[:, 0] - 0.22) / 0.015) * _sigmoid((0.36 - s[:, 0]) / 0.015)
    out[pr, 3] = (vc - leaving)[pr]
    out[pr, 4] = (vt + leaving * into)[pr]
    return out


def synthetic_transitions(n_traj: int, n_steps: int = 4, seed: int = 0) -> Transitions:
    """Multi-step random trajectories (so partly poured states occur) of :func:`analytic_step`."""
    rng = np.random.default_rng(seed)
    s = np.column_stack(
        [
            rng.uniform(0.32, 0.5, n_traj),
            rng.uniform(0.08, 0.3, n_traj),
            np.zeros(n_traj),
            np.ones(n_traj),
            np.zeros(n_traj),
        ]
    )
    rows: dict[str, list[Any]] = {k: [] for k in ("s", "a", "s_next", "traj", "step")}
    for t in range(n_steps):
        pour = rng.random(n_traj) < 0.5
        a = np.where(
            pour[:, None],
            np.column_stack([np.full(n_traj, POUR), rng.uniform(0, 2.2, n_traj), rng.uniform(0, 1, n_traj)]),
            np.column_stack([np.full(n_traj, MOVE), rng.uniform(0.1, 0.52, n_traj), rng.uniform(0.06, 0.36, n_traj)]),
        )
        nxt = analytic_step(s, a)
        for k, v in (("s", s), ("a", a), ("s_next", nxt), ("traj", np.arange(n_traj)), ("step", np.full(n_traj, t))):
            rows[k].append(v)
        s = nxt
    arr = {k: np.concatenate(v) for k, v in rows.items()}
    return Transitions.from_arrays(**arr, meta={"world": "source", "generator": "synthetic", "seed": seed})


def synthetic_generator(
    cfg: Any, shard_dir: Path | None = None, progress: bool = False, world_cfg: Any = None
) -> Transitions:
    """Drop-in for :func:`dynamics.data.generate_source_dataset`: size and seed from ``cfg.data``."""
    d = cfg.data
    return synthetic_transitions(d.n_batches * d.batch_size, n_steps=d.max_actions, seed=d.seed)
