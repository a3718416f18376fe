"""Initial water sampling: per-slot jitter and its switch."""

import numpy as np
import pytest

from sim.engine.config import ConfigError, SimConfig
from sim.engine.scene import EnvSpec, WaterBlock, sample_water


def _spec():
    return EnvSpec(bodies=[], water=[WaterBlock((0.1, 0.1), (0.17, 0.15))])


def test_jitter_zero_is_a_regular_lattice_and_default_jitter_differs_per_seed():
    a = sample_water(_spec(), 0.01, 4, np.random.default_rng([0, 0]), jitter=0.0)
    b = sample_water(_spec(), 0.01, 4, np.random.default_rng([0, 1]), jitter=0.0)
    np.testing.assert_array_equal(a, b)
    assert len(np.unique(np.round(a[:, 0], 6))) == 14  # 7 cells x 2 sub-columns
    c = sample_water(_spec(), 0.01, 4, np.random.default_rng([0, 0]))
    d = sample_water(_spec(), 0.01, 4, np.random.default_rng([0, 1]))
    assert not np.array_equal(c, d) and np.abs(c - a).max() <= 0.25 * 0.005 + 1e-7


@pytest.mark.parametrize("bad", [-0.1, 0.6])
def test_jitter_out_of_range_is_refused(bad):
    with pytest.raises(ConfigError, match="jitter"):
        SimConfig(jitter=bad)
