"""The solver settings come from the world (``world.sim``; the rest are sim.engine.config.SimConfig's defaults)."""

from pathlib import Path

CONFIGS = Path(__file__).parents[1] / "configs"


def test_every_config_group_is_composed():
    """A group in no defaults list changes nothing when edited (configs/sim/ was one: SimConfig's defaults with
    a 0.60 x 0.45 m tank, while the worlds' solver is world.sim, 0.60 x 0.60 m)."""
    import yaml

    defaults = yaml.safe_load((CONFIGS / "config.yaml").read_text())["defaults"]
    # "world: default", or "override hydra/launcher: joblib" (a group of Hydra's own, under configs/hydra/)
    groups = {next(iter(d)).removeprefix("override ").split("/")[0] for d in defaults if isinstance(d, dict)}
    assert {p.name for p in CONFIGS.iterdir() if p.is_dir()} <= groups


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
