"""The shipped Hydra config for the solver matches SimConfig (no drift between yaml and code)."""

from pathlib import Path

import yaml

from sim.config import SimConfig


def test_default_yaml_builds_the_default_config():
    data = yaml.safe_load((Path(__file__).parents[1] / "configs" / "sim" / "default.yaml").read_text())
    assert SimConfig.from_mapping(data) == SimConfig()
