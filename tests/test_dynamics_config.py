"""Dynamics config: YAML mirror, validation messages, and which fields each cache hash covers."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from dynamics import DynamicsConfig, DynamicsError, data_hash, model_hash

CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "dynamics"


def test_yaml_mirrors_dataclass_defaults():
    d = yaml.safe_load((CONFIGS / "default.yaml").read_text())
    assert d == DynamicsConfig().to_dict()
    assert DynamicsConfig.from_dict(d) == DynamicsConfig()


def test_hydra_compose_with_overrides_and_quick_preset():
    from dynamics.evaluate import compose_config

    c = compose_config("default", ["data.n_batches=4", "train.max_epochs=50", "model.hidden=[32,32]"])
    assert (c.data.n_batches, c.train.max_epochs, c.model.hidden) == (4, 50, (32, 32))
    q = compose_config("quick")
    assert q.data.n_batches == 4 and q.replace(data=DynamicsConfig().data) == DynamicsConfig()


@pytest.mark.parametrize(
    "d, match",
    [
        ({"bogus": 1}, r"unknown dynamics config key\(s\) \['bogus'\]"),
        ({"data": {"n_batchez": 3}}, r"unknown dynamics.data key\(s\) \['n_batchez'\]"),
        ({"data": {"p_pour": 1.5}}, r"data.p_pour = 1.5: allowed a probability in \[0, 1\]"),
        ({"data": {"min_actions": 5, "max_actions": 3}}, r"data.max_actions = 3: allowed 5..6"),
        ({"data": {"near_target_y": [0.3, 0.1]}}, r"data.near_target_y = \[0.3, 0.1\]: allowed a finite range"),
        ({"model": {"activation": "gelu"}}, r"model.activation = 'gelu': allowed one of"),
        ({"model": {"hidden": []}}, r"model.hidden = \[\]"),
        ({"train": {"val_fraction": 1.0}}, r"train.val_fraction = 1.0: allowed \(0, 1\)"),
        ({"train": {"lr": 0}}, r"train.lr = 0: allowed > 0"),
        ({"train": {"loss": "l2"}}, r"train.loss = 'l2': allowed one of \('distance', 'scaled_mse'\)"),
        ({"train": {"lr_schedule": "step"}}, r"train.lr_schedule = 'step': allowed one of \('constant', 'cosine'\)"),
    ],
)
def test_bad_values_name_field_and_range(d, match):
    with pytest.raises(DynamicsError, match=match):
        DynamicsConfig.from_dict(d)


def test_hash_scopes():
    base = DynamicsConfig()
    dh, mh = data_hash(base), model_hash(base)
    # data fields change both hashes
    c = DynamicsConfig.from_dict({"data": {"n_batches": 3}})
    assert data_hash(c) != dh and model_hash(c) != mh
    # model / training fields change only the checkpoint hash
    for d in ({"train": {"lr": 1e-3}}, {"train": {"lr_schedule": "constant"}}, {"model": {"hidden": [64]}}):
        c = DynamicsConfig.from_dict(d)
        assert data_hash(c) == dh and model_hash(c) != mh
    # evaluation, cache location and progress bars change neither
    c = DynamicsConfig.from_dict({"eval": {"seed": 5}, "cache_root": "/elsewhere", "progress": False})
    assert data_hash(c) == dh and model_hash(c) == mh


def test_the_hashes_are_digests_of_every_setting():
    """Every model and training field, at every value, is part of the model hash; every data field (the focused
    pours' fields too when there are none) and every solver setting of the world, at every value, of the data hash."""
    import dataclasses

    from sim.world import DEFAULT_CONFIG

    base = DynamicsConfig()
    single = base.replace(model=dataclasses.replace(base.model, ensemble=1))
    assert model_hash(single) != model_hash(base) and data_hash(single) == data_hash(base)
    constant = base.replace(train=dataclasses.replace(base.train, lr_schedule="constant"))
    assert model_hash(constant) != model_hash(base)
    no_pours = base.replace(data=dataclasses.replace(base.data, pour_batches=0))
    assert data_hash(no_pours.replace(data=dataclasses.replace(no_pours.data, pour_x=(0.2, 0.3)))) != data_hash(
        no_pours
    )
    w = yaml.safe_load(DEFAULT_CONFIG.read_text())
    for k, v in (
        ("viscosity", 0.001),
        ("stretch_relax", 0.01),
        ("boundary_density", False),
        ("box_normals", "central"),
    ):
        assert data_hash(base, {**w, "sim": {**w["sim"], k: v}}) != data_hash(base), k
    # the solver's defaults are filled in: a setting spelled out at its default is the same world
    assert data_hash(base, {**w, "sim": {**w["sim"], "viscosity": 0.0}}) == data_hash(base)


def test_another_format_version_is_refused_with_both_versions_and_the_fix(tmp_path):
    import torch

    from dynamics import LearnedDynamics, Transitions
    from dynamics.config import DATA_FORMAT_VERSION, MODEL_FORMAT_VERSION
    from dynamics.train import SHIPPED_DIR

    for pattern, cls, version in (
        ("source-*.pt", Transitions, DATA_FORMAT_VERSION),
        ("model-*.pt", LearnedDynamics, MODEL_FORMAT_VERSION),
    ):
        payload = torch.load(sorted(SHIPPED_DIR.glob(pattern))[0], weights_only=True)
        path = tmp_path / pattern.replace("*", "old")
        torch.save({**payload, "version": version - 1}, path)
        with pytest.raises(
            DynamicsError,
            match=rf"format version {version - 1}, this code reads version {version}; "
            rf"delete .* and (regenerate it|retrain) with `python -m dynamics.train`",
        ):
            cls.load(path)


def test_world_content_is_part_of_the_data_hash(tmp_path):
    from sim.world import DEFAULT_CONFIG

    w = yaml.safe_load(DEFAULT_CONFIG.read_text())
    same = tmp_path / "same.yaml"
    same.write_text(yaml.safe_dump(w))
    w["target_cup"]["x"] = 0.25
    moved = tmp_path / "moved.yaml"
    moved.write_text(yaml.safe_dump(w))
    base = data_hash(DynamicsConfig())
    assert data_hash(DynamicsConfig.from_dict({"data": {"world": str(same)}})) == base
    assert data_hash(DynamicsConfig.from_dict({"data": {"world": str(moved)}})) != base
    with pytest.raises(DynamicsError, match="no such world config file"):
        data_hash(DynamicsConfig.from_dict({"data": {"world": str(tmp_path / "missing.yaml")}}))


def test_the_plant_is_not_part_of_the_source_data_hash():
    """The source world has no plant: changing it keeps the source dataset (and the shipped file) valid,
    while the evaluation sets, which hold target-world data, key on it."""
    from dynamics.config import plant_dict
    from sim.world import DEFAULT_CONFIG

    c = DynamicsConfig()
    w = yaml.safe_load(DEFAULT_CONFIG.read_text())
    w["plant"]["leaves"][0]["center"] = [0.065, 0.26]
    assert data_hash(c, w) == data_hash(c)
    assert plant_dict(c.data, w) != plant_dict(c.data)
    w["target_cup"]["x"] = 0.25  # the rest of the world still counts
    assert data_hash(c, w) != data_hash(c)


def test_the_goal_range_is_not_part_of_the_source_data_identity():
    """No goal enters the source data (goals only pose planning problems): another goal range keeps the
    dataset, its shards and the shipped file; the start region, which the generator draws from, counts."""
    from dynamics.data import shard_identity
    from sim.world import DEFAULT_CONFIG

    c = DynamicsConfig()
    w = yaml.safe_load(DEFAULT_CONFIG.read_text())
    w["problems"]["goal"] = [0.3, 0.5]
    assert data_hash(c, w) == data_hash(c) and shard_identity(c.data, w) == shard_identity(c.data, None)
    w["problems"]["start_x"] = [0.38, 0.50]
    assert data_hash(c, w) != data_hash(c)


def test_the_solver_arch_is_not_part_of_the_data_hash():
    """A GPU run (world.sim.arch=gpu) uses the shipped, CPU-made data instead of simulating them again: CPU and GPU
    make the same data within benchmarks.check_arch's tolerances."""
    from sim.world import DEFAULT_CONFIG

    c = DynamicsConfig()
    w = yaml.safe_load(DEFAULT_CONFIG.read_text())
    gpu = {**w, "sim": {**w["sim"], "arch": "gpu"}}
    assert data_hash(c, gpu) == data_hash(c, w) == data_hash(c)
    assert model_hash(c, world_cfg=gpu) == model_hash(c)
    assert data_hash(c, {**w, "sim": {**w["sim"], "dt": w["sim"]["dt"] / 2}}) != data_hash(c)  # physics still counts


def test_world_given_as_object_or_mapping_overrides_the_file():
    """The main job passes its own (possibly overridden) world config; equal worlds hash equally."""
    from omegaconf import OmegaConf

    from sim.world import DEFAULT_CONFIG, WorldConfig

    c = DynamicsConfig()
    w = yaml.safe_load(DEFAULT_CONFIG.read_text())
    assert data_hash(c) == data_hash(c, WorldConfig.load()) == data_hash(c, OmegaConf.create(w))
    w["skills"]["move"]["peak_speed"] = 0.2
    assert data_hash(c, w) != data_hash(c) and model_hash(c, world_cfg=w) != model_hash(c)
    w["skills"]["max_actions"] = 9
    with pytest.raises(DynamicsError, match="not a valid world config"):
        data_hash(c, w)
