"""W&B tracking: offline by default, one run per (method, seed), resumed under the same id after a kill."""

from __future__ import annotations

import pytest

from active.tracking import Tracker


def test_a_resumed_run_continues_the_same_wandb_run(tmp_path, monkeypatch):
    """Two trackers with the same id (a run killed after iteration 1, started again) log to one W&B run: the
    offline records carry the same run id, which `wandb sync` merges into one curve."""
    pytest.importorskip("wandb")
    monkeypatch.setenv("WANDB_MODE", "offline")
    ids = []
    for step in (1, 2):
        t = Tracker(
            "offline",
            "active-mde-test",
            "quick-random_plan-seed0",
            {"seed": 0},
            tmp_path,
            group="quick-random_plan",
            run_id="0123456789abcdef-random_plan-seed0",
        )
        assert t.run is not None, "W&B could not start offline"
        ids.append(t.run.id)
        t.log({"test_success": 0.5}, step=step)
        t.finish()
    assert ids == ["0123456789abcdef-random_plan-seed0"] * 2
    runs = sorted((tmp_path / "wandb").glob("offline-run-*"))
    assert len(runs) == 2 and all("-0123456789abcdef-random_plan-seed0" in r.name for r in runs)


def test_a_bad_mode_is_refused_naming_the_field(tmp_path):
    with pytest.raises(ValueError, match=r"wandb.mode = 'loud': allowed one of"):
        Tracker("loud", "p", "n", {}, tmp_path)
