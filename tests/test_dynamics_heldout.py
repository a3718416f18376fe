"""benchmarks.dynamics_heldout: variants trained per seed, scored on batches past the training data."""

from __future__ import annotations

import json

import pytest

from benchmarks import dynamics_heldout
from tests.doubles.synthetic import synthetic_generator

TINY = (
    "data.n_batches=1,data.pour_batches=0,data.batch_size=16,data.max_actions=4,model.hidden=[8],train.max_epochs=2,"
    "progress=false"
)


def test_variants_are_scored_on_held_out_batches(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # the default cache_root is relative to the working directory
    monkeypatch.setattr(
        "dynamics.data.generate_source_dataset",
        lambda cfg, shard_dir=None, progress=False, world_cfg=None: synthetic_generator(cfg),
    )
    out = tmp_path / "r.json"
    dynamics_heldout.main(
        [
            "--heldout-batches",
            "2",
            "--seeds",
            "0",
            "1",
            "--out",
            str(out),
            "--variant",
            f"a={TINY}",
            "--variant",
            f"b={TINY},train.lr_schedule=constant,model.hidden=[8,8]",
        ]
    )
    r = json.loads(out.read_text())
    assert r["heldout"] == {"batches": [1, 2], "transitions": 16 * 4}  # 16 trajectories of 4 synthetic steps
    for name in ("a", "b"):
        v = r["variants"][name]
        assert [row["seed"] for row in v["per_seed"]] == [0, 1]
        assert v["per_seed"][0]["pour_mean_d"] != v["per_seed"][1]["pour_mean_d"]  # two models
        assert v["mean_of_seeds"]["n_pour"] > 0 and v["mean_of_seeds"]["pour_mae_v_tgt"] > 0
    assert r["variants"]["a"]["per_seed"][0] != r["variants"]["b"]["per_seed"][0]
    assert r["variants"]["b"]["overrides"][-1] == "model.hidden=[8,8]"  # a comma inside brackets stays
    assert "mean of seeds" in capsys.readouterr().out
    with pytest.raises(ValueError, match=r"--heldout-batches 1: allowed > data.n_batches = 1"):
        dynamics_heldout.run({"a": TINY.split(",")}, [0], 1)
    with pytest.raises(ValueError, match=r"variant b: its data.\* differ"):
        dynamics_heldout.run({"a": TINY.split(","), "b": [*TINY.split(","), "data.seed=1"]}, [0], 2)


def test_variants_with_other_data_are_scored_on_a_given_dataset(tmp_path, monkeypatch):
    """--heldout-data: variants whose data differ, scored on the rows of another dataset none trained on."""
    import numpy as np

    from dynamics import load_or_generate_dataset
    from dynamics.evaluate import compose_config

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(
        "dynamics.data.generate_source_dataset",
        lambda cfg, shard_dir=None, progress=False, world_cfg=None: synthetic_generator(cfg),
    )
    a = load_or_generate_dataset(compose_config("default", TINY.split(",")))
    b = load_or_generate_dataset(compose_config("default", [*TINY.split(","), "data.seed=1"]))
    held = type(a).concat([a.subset(np.arange(8)), b], meta=dict(b.meta))  # 8 rows variant a trained on
    path = held.save(tmp_path / "held.pt")
    r = dynamics_heldout.run({"a": TINY.split(","), "c": [*TINY.split(","), "data.seed=2"]}, [0], 2, path)
    assert r["heldout"]["transitions"] == len(held) and r["heldout"]["unseen_transitions"] == len(b)
    for v in r["variants"].values():
        assert {"clean_mae_v_tgt", "clean_bias_v_tgt", "n_clean"} <= set(v["mean_of_seeds"])
