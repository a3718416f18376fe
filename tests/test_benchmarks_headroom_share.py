"""``benchmarks.headroom_share``: the leaf knob changes the first leaf only, and a bad argument is refused before any
planning or simulation."""

from __future__ import annotations

import pytest

from active.run import compose_config
from benchmarks.headroom_share import leaf_world, main


def test_the_leaf_knob_sets_the_first_leafs_span_and_height_and_nothing_else():
    world = compose_config([])["world"]
    w = leaf_world(world, 0.05, 0.30)
    first = w["plant"]["leaves"][0]
    assert list(first["center"]) == [0.025, 0.30] and list(first["radii"]) == [
        0.025,
        world["plant"]["leaves"][0]["radii"][1],
    ]
    assert first["angle"] == world["plant"]["leaves"][0]["angle"]
    assert w["plant"]["leaves"][1:] == world["plant"]["leaves"][1:]
    assert {k: v for k, v in w.items() if k != "plant"} == {k: v for k, v in world.items() if k != "plant"}
    assert world["plant"]["leaves"][0]["radii"][0] == 0.045  # the given world is left as it was


def test_a_bad_problem_count_is_refused_before_any_compute(capsys):
    with pytest.raises(SystemExit):
        main(["--problems", "0"])
    assert "--problems 0: allowed an integer >= 1" in capsys.readouterr().err


def test_a_leaf_alone_is_the_whole_plant():
    from sim.world import WorldConfig

    world = compose_config([])["world"]
    w = leaf_world(world, 0.05, 0.30, alone=True)
    assert len(w["plant"]["leaves"]) == 1 and list(w["plant"]["leaves"][0]["center"]) == [0.025, 0.30]
    assert w["plant"]["stem_height"] < world["plant"]["stem_height"]
    shapes = WorldConfig.from_mapping(w).plant_shapes()  # a valid world: a stub of a stem and the leaf
    assert [sh.kind for sh in shapes] == ["capsule", "ellipse"]
