"""The three commands run end to end on tiny synthetic stand-ins for the simulator data."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.doubles.synthetic import synthetic_generator, synthetic_transitions


@pytest.fixture
def no_simulator(monkeypatch):
    """Training data and evaluation sets from the synthetic world (with a plant jitter column)."""
    monkeypatch.setattr("dynamics.data.generate_source_dataset", lambda cfg, **k: synthetic_generator(cfg))

    def fake_eval_set(data, world, n_batches, seed, **k):
        ds = synthetic_transitions(4 * n_batches, n_steps=3, seed=seed + (world == "target"))
        ds.plant_jitter[:] = np.array([0.004, 0.0, 0.02]) if world == "target" else 0.0
        ds.meta.update(world=world, counts={"categories": {}})
        return ds

    monkeypatch.setattr("dynamics.evaluate.generate_transitions", fake_eval_set)


OVERRIDES = [
    "progress=false",
    "data.n_batches=1",
    "data.pour_batches=0",
    "data.batch_size=12",
    "model.hidden=[16]",
    "train.max_epochs=3",
    "eval.source_batches=1",
    "eval.target_batches=2",
]


def test_train_evaluate_bench_commands(tmp_path, no_simulator, capsys):
    from benchmarks import dynamics as bench
    from dynamics import evaluate, train

    over = OVERRIDES + [f"cache_root={tmp_path / 'cache'}"]
    train.main(over + [f"hydra.run.dir={tmp_path / 'hydra'}"])
    assert "validation split (source world)" in capsys.readouterr().out
    result = evaluate.main(["--out", str(tmp_path / "eval"), *over])
    saved = json.loads((tmp_path / "eval" / "dynamics_eval.json").read_text())
    assert (tmp_path / "eval" / "dynamics_eval.png").stat().st_size > 10_000
    groups = saved["groups"]
    assert set(groups) == {"source_val", "source_test", "target_far", "target_near"}
    n_target = groups["target_far"]["all"]["n"] + groups["target_near"]["all"]["n"]
    assert n_target == 2 * 4 * 3 == len(saved["target_scatter"]["d"])
    near = np.asarray(saved["target_scatter"]["clearance"]) < saved["config"]["eval"]["near_radius"]
    assert near.sum() == groups["target_near"]["all"]["n"]
    assert result["model_hash"] == saved["model_hash"]
    out = capsys.readouterr().out
    assert "[target_near]" in out and "mae_v_tgt" in out
    res = bench.main(["--out", str(tmp_path / "bench.json"), "--min-seconds", "0.005", "--repeats", "1", *over])
    assert res["model"].endswith("model.pt")  # the checkpoint trained above, not an untrained net
    batches = {(r["path"], r["batch"]) for r in res["rows"]}
    assert {
        ("predict (torch) pour", 1),
        ("predict (torch) mixed", 1024),
        ("predict_one (numpy) move", 1),
        ("predict_one (numpy) pour", 1),
    } <= batches
    assert all(r["us_per_call"] > 0 for r in res["rows"])
    assert json.loads((tmp_path / "bench.json").read_text())["rows"] == res["rows"]
