"""MDE labels: how far the learned model's prediction lands from what the target world did.

A transition (s, a, s') executed in the target world is labelled d(f_hat(s, a), s'), the task's state
distance (``task.state_distance``, weights from the world) between the model's prediction and the outcome.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import torch

from task import state_distance


def label_transitions(
    dynamics: Any, s: np.ndarray, a: np.ndarray, s_next: np.ndarray, weights: Mapping[str, float]
) -> np.ndarray:
    """MDE labels d(f_hat(s, a), s')."""
    with torch.no_grad():
        pred = dynamics.predict(torch.as_tensor(s, dtype=torch.float32), torch.as_tensor(a, dtype=torch.float32))
    return state_distance(pred.double().numpy(), s_next, weights)


def stack_steps(results: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (s, a, s') arrays of every step of the stable results (empty arrays when there are none)."""
    steps = [st for r in results if not r.unstable for st in r.steps]
    if not steps:
        return np.zeros((0, 5)), np.zeros((0, 3)), np.zeros((0, 5))
    return (np.stack([st.s for st in steps]), np.stack([st.a for st in steps]), np.stack([st.s_next for st in steps]))
