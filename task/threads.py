"""Torch's intra-op thread count for the length of a block, defined once for every package that sets it.

One "off" value: ``0`` leaves torch's setting alone. The MDE, the planner and the dynamics model's training
each take a thread count from their config (``mde.num_threads``, ``planner.torch_threads``,
``dynamics.train.threads``) and run their torch work inside :func:`torch_threads`.
"""

from __future__ import annotations

import contextlib
from typing import Iterator

import torch

#: the thread count that leaves torch's setting as it is
KEEP_TORCH_THREADS = 0


@contextlib.contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Run the block with ``n`` torch intra-op threads, then restore the previous setting.

    ``n`` = 0 (:data:`KEEP_TORCH_THREADS`) leaves torch's setting alone. Why a fixed count: on a CPU shared
    with other busy processes 1 thread is faster and much steadier than 2 (OpenMP threads wait on each
    other), and a fixed count keeps floating-point reductions, and so results, the same from run to run.
    """
    if isinstance(n, bool) or int(n) != n or n < 0:
        raise ValueError(
            f"torch threads = {n!r}: allowed an integer >= 1, or {KEEP_TORCH_THREADS} to leave torch's setting alone"
        )
    prev = torch.get_num_threads()
    if n == KEEP_TORCH_THREADS or n == prev:
        yield
        return
    torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(prev)
