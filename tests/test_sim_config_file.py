"""The shipped Hydra config for the solver matches SimConfig (no drift between yaml and code)."""

from pathlib import Path

import yaml

from sim.config import SimConfig


def test_default_yaml_builds_the_default_config():
    data = yaml.safe_load((Path(__file__).parents[1] / "configs" / "sim" / "default.yaml").read_text())
    assert SimConfig.from_mapping(data) == SimConfig()


def test_fine_world_keeps_the_default_geometry_at_half_the_grid_spacing():
    from active.run import compose_config
    from sim.world import WorldConfig

    fine = WorldConfig.from_mapping(compose_config(["world=fine"])["world"])
    default = WorldConfig.from_mapping(compose_config([])["world"])
    assert fine.sim_config(1).dx == default.sim_config(1).dx / 2
    assert fine.floor == default.floor and fine.target_pose() == default.target_pose()
    # room for the full cup at 4x the particles per area
    full = default.controlled_cup.inner_width * default.controlled_cup.fill_height / fine.sim_config(1).dx ** 2 * 4
    assert fine.sim_config(1).max_particles >= full
