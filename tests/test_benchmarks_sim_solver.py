"""The solver benchmark's scenes (the timing itself is a benchmark, not a test)."""

import pytest

from benchmarks.sim_solver import SCENES, _setup, bench


def test_an_unknown_scene_is_refused_naming_the_allowed_ones():
    with pytest.raises(ValueError, match=r"scene = 'dam'.*allowed one of \('pouring', 'world'\)"):
        bench(envs=(1,), seconds=0.0, scene="dam")


@pytest.mark.parametrize("scene", SCENES)
def test_each_scene_builds_one_environment_per_slot(scene):
    cfg, specs = _setup(scene, 3, 0.01, "cpu")
    assert cfg.n_envs == 3 and len(specs) == 3
    assert all(s.water for s in specs)  # every environment has water to move
