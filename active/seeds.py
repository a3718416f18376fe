"""Every random stream of a run is derived from keys, never from history.

A run killed and resumed, a run served alone or batched with others (:mod:`active.lockstep`), and a
run of one seed inside a sweep of many all draw the same numbers, because each stream's seed is a
function of (seed, purpose, iteration, index) only.
"""

from __future__ import annotations

import zlib
from typing import Any

import numpy as np


def derive_seed(*keys: Any) -> int:
    """A 32-bit seed from (seed, purpose, iteration, index...): independent of run history."""
    ints = [k if isinstance(k, int) else zlib.crc32(str(k).encode()) for k in keys]
    return int(np.random.SeedSequence(ints).generate_state(1)[0])
