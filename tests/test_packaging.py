"""What a researcher expects of the package: console commands, SLURM presets that compose, a license and a citation."""

from __future__ import annotations

from importlib import import_module
from pathlib import Path

import pytest
import tomllib
import yaml

ROOT = Path(__file__).resolve().parents[1]


def test_console_commands_name_callables_of_the_package():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert set(scripts) == {"active-mde", "active-mde-report", "active-mde-ladder"}
    for target in scripts.values():
        module, _, name = target.partition(":")
        assert callable(getattr(import_module(module), name)), target


@pytest.mark.parametrize("preset, gpus", [("slurm_cpu", 0), ("slurm_gpu", 1)])
def test_slurm_presets_compose_and_requeue_on_timeout(preset, gpus):
    """The presets are Hydra's submitit SLURM launcher with resources and a requeue budget: a job that reaches its
    time limit is requeued and resumes from its last saved iteration."""
    from hydra import compose, initialize_config_dir

    from active.run import CONFIG_DIR, register_resolvers

    register_resolvers()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose(
            config_name="config",
            overrides=[f"hydra/launcher={preset}", "hydra.launcher.partition=p"],
            return_hydra_config=True,
        )
    launcher = cfg.hydra.launcher
    assert launcher._target_.endswith("submitit_launcher.SlurmLauncher") and launcher.partition == "p"
    assert launcher.gpus_per_node == gpus and launcher.cpus_per_task >= 2 and launcher.max_num_timeout >= 1


def test_license_and_citation_are_there():
    assert "MIT License" in (ROOT / "LICENSE").read_text()
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["version"] == tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert "Model Preconditions" in cff["preferred-citation"]["title"]
