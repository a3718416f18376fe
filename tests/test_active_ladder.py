"""The ladder command on a tiny configuration: every rung runs, the JSON holds the issue's keys."""

import json

import pytest

from active.ladder import RUNGS, main, table


@pytest.mark.slow  # compiles its own kernels: about 30-70 s in a fresh clone (CI time)
def test_tiny_ladder_writes_every_rung(tmp_path, capsys):
    from tests.test_active_run import tiny_overrides

    overrides = tiny_overrides(tmp_path / "cache")
    main(
        [
            "--out",
            str(tmp_path / "ladder"),
            "--slots",
            "2",
            "--thetas",
            "1.45",
            "--problems",
            "2",
            "--ceiling-trajectories",
            "5",
            *overrides,
        ]
    )
    res = json.loads((tmp_path / "ladder" / "ladder.json").read_text())
    rep = res["reproducibility"]
    assert len(rep["pours"]) == 1
    assert rep["max_std"] == max(rep["slots_std"] + rep["approaches_std"] + rep["offsets_std"])
    assert 0.0 <= rep["pours"][0]["slots_mean"] <= 1.0
    for name in ("source_model_only", "target_model_only"):
        assert res[name]["n"] == 2 and 0.0 <= res[name]["success"] <= res[name]["found"] <= 1.0
    assert sum(res["target_model_only"]["categories"].values()) == round(2 * res["target_model_only"]["found"])
    ceil = res["ceiling"]
    assert ceil["train_trajectories"] == 5 and ceil["train_transitions"] >= 5 and ceil["n"] == 2
    assert 0.0 <= ceil["success"] <= ceil["found"] <= 1.0
    assert sum(ceil["categories"].values()) == round(2 * ceil["found"])  # how the found plans ended
    for rung in (res["source_model_only"], res["target_model_only"], ceil):  # which problems failed, and how
        rows = rung["problems"]
        assert len(rows) == 2 and sum(r["found"] for r in rows) == round(2 * rung["found"])
        assert sum(r.get("goal_reached", False) for r in rows) == round(2 * rung["success"])
        assert all(0.3 <= r["goal"] <= 0.8 and len(r["start"]) == 3 for r in rows)
        assert all(r["category"] in ceil["categories"] for r in rows if r["found"])
    for skill in ceil["precondition_on_train"].values():  # in sample and held out by trajectory
        assert 0.0 <= skill["in_sample_admitted"] <= 1.0 and 0.0 <= skill["heldout_admitted"] <= 1.0
    assert res["seconds"] > 0
    out = capsys.readouterr().out
    assert "ceiling.success" in out and "wrote" in out and "held out by trajectory" in out
    # the saved training transitions are reused without simulating: same data, same MDE diagnostics
    data = tmp_path / "ladder" / "ceiling_train.npz"
    import numpy as np

    with np.load(data) as f:
        assert str(f["plant_on_contact"]) == "stuck"  # the world it was made in (checked when reused)
    main(
        [
            "--out",
            str(tmp_path / "again"),
            "--rungs",
            "ceiling",
            "--problems",
            "2",
            "--ceiling-data",
            str(data),
            *overrides,
        ]
    )
    again = json.loads((tmp_path / "again" / "ladder.json").read_text())["ceiling"]
    assert again["train_transitions"] == ceil["train_transitions"]
    assert again["precondition_on_train"] == ceil["precondition_on_train"]
    # --ceiling-seeds: one training set and test set per seed, each saved; the mean over them
    main(
        [
            "--out",
            str(tmp_path / "seeds"),
            "--rungs",
            "ceiling",
            "--problems",
            "2",
            "--ceiling-trajectories",
            "3",
            "--ceiling-seeds",
            "0",
            "1",
            "--",
            *overrides,
        ]
    )
    many = json.loads((tmp_path / "seeds" / "ladder.json").read_text())["ceiling"]
    assert many["seeds"] == [0, 1] and [r["seed"] for r in many["per_seed"]] == [0, 1]
    assert "problems" not in many and all(len(r["problems"]) == 2 for r in many["per_seed"])
    assert many["success"] == pytest.approx((many["per_seed"][0]["success"] + many["per_seed"][1]["success"]) / 2)
    assert all((tmp_path / "seeds" / f"ceiling_train_seed{s}.npz").is_file() for s in (0, 1))


def test_subcell_offsets_cover_one_cell_without_repeats():
    import numpy as np

    from active.ladder import subcell_offsets

    for n in (2, 5, 32):
        o = subcell_offsets(n, 0.01)
        assert o.shape == (n, 2) and len(np.unique(o, axis=0)) == n
        assert (o >= 0).all() and (o < 0.01).all()
    assert np.allclose(subcell_offsets(32, 0.01)[:8, 0], np.arange(8) * 0.01 / 8)


def test_unknown_rung_is_refused_before_compute(tmp_path):
    from active.ladder import run_ladder
    from active.run import compose_config

    with pytest.raises(ValueError, match="allowed any of"):
        run_ladder(compose_config(["experiment=tiny"]), tmp_path, ["ceiling", "floor"], [1.4], 0.5, 2, 4)
    assert not (tmp_path / "ladder.json").exists()


def test_table_marks_targets():
    text = table(
        {"reproducibility": {"max_std": 0.02, "pours": []}, "source_model_only": {"found": 0.95, "success": 0.5}}
    )
    lines = {l.split()[0]: l for l in text.splitlines()}
    assert lines["reproducibility.max_std"].endswith("NO")
    assert lines["source_model_only.found"].endswith("yes")
    assert lines["ceiling.success"].split()[1] == "-"
    assert set(RUNGS) == {"reproducibility", "source_model_only", "target_model_only", "ceiling"}


def test_model_only_rungs_over_several_models_report_mean_range_and_each_model():
    """--model-seeds: one training draw moves the source rung by up to 0.4, so the rung reports the mean
    over models, the range, and every model's record; one model keeps the record it always had."""
    from active.ladder import _mean_over

    def rec(seed, found, success, err):
        return {
            "model_seed": seed,
            "n": 30,
            "found": found,
            "success": success,
            "mean_abs_goal_error": err,
            "categories": {"successful_pour": 1},
            "spill_over_limit": 0,
            "plan_seconds": 10.0,
        }

    rows = [rec(0, 0.9, 0.4, 0.06), rec(1, 0.8, 0.2, None)]
    out = _mean_over(rows, "model_seed")
    assert out["found"] == pytest.approx(0.85) and out["success"] == pytest.approx(0.3)
    assert out["success_range"] == [0.2, 0.4] and out["mean_abs_goal_error"] == 0.06  # None: no plan executed
    assert out["model_seeds"] == [0, 1] and out["per_model_seed"] == rows and out["plan_seconds"] == 20.0
    assert "(mean of 2 models: 0.20-0.40)" in table({"source_model_only": out})
    one = _mean_over([rec(3, 0.5, 0.1, 0.08)], "model_seed")
    assert "model_seed" not in one and one["success"] == 0.1 and "per_model_seed" not in one


def test_ceiling_subset_keeps_half_plans_half_random_actions():
    """--ceiling-data with --ceiling-trajectories k: the first k/2 of each half of the saved set, renumbered."""
    import numpy as np

    from active.ladder import ceiling_subset

    d = {
        "s": np.arange(10.0)[:, None] * np.ones((1, 5)),
        "a": np.zeros((10, 3)),
        "s_next": np.zeros((10, 5)),
        "trajectory": np.array([0, 0, 1, 2, 2, 3, 4, 5, 5, 7]),
        "category": np.array(list("abcdefgh")),
    }
    r = ceiling_subset(d, 4)  # plans 0, 1 and random-action trajectories 4, 5 of 8
    np.testing.assert_array_equal(r["trajectory"], [0, 0, 1, 2, 3, 3])
    np.testing.assert_array_equal(r["category"], list("abef"))
    np.testing.assert_array_equal(r["s"][:, 0], [0, 1, 2, 6, 7, 8])
    assert "plant_on_contact" not in r  # nothing recorded, nothing invented
    assert str(ceiling_subset({**d, "plant_on_contact": np.array("stuck")}, 4)["plant_on_contact"]) == "stuck"
    with pytest.raises(ValueError, match=r"--ceiling-trajectories 9 with --ceiling-data: allowed 2..8"):
        ceiling_subset(d, 9)
    with pytest.raises(SystemExit, match=r"--ceiling-trajectories 1: allowed >= 2"):
        main(["--out", "unused", "--ceiling-trajectories", "1"])


def test_ceiling_over_several_training_sets_reports_mean_range_and_each_set():
    """--ceiling-seeds: one training set moves the ceiling from 0.00 to 0.60, so the rung reports the mean
    over sets (each with its own test problems), the range, and every set's record."""
    from active.ladder import _mean_over

    def rec(seed, found, success):
        return {
            "seed": seed,
            "train_trajectories": 128,
            "n": 30,
            "found": found,
            "success": success,
            "precondition_on_train": {},
            "plan_seconds": 5.0,
        }

    rows = [rec(0, 0.1, 0.0), rec(1, 0.6, 0.47), rec(2, 0.2, 0.05)]
    out = _mean_over(rows, "seed")
    assert out["success"] == pytest.approx(0.52 / 3) and out["found"] == pytest.approx(0.3)
    assert out["success_range"] == [0.0, 0.47] and out["seeds"] == [0, 1, 2] and out["per_seed"] == rows
    assert "mean_abs_goal_error" not in out and out["plan_seconds"] == 15.0
    assert "(mean of 3 training sets: 0.00-0.47)" in table({"ceiling": out})


def test_ceiling_seeds_and_files_are_checked_before_compute(tmp_path):
    from active.ladder import _ceiling_runs

    runs = _ceiling_runs(0, [4, 5], None, tmp_path)
    assert runs == [(4, tmp_path / "ceiling_train_seed4.npz", False), (5, tmp_path / "ceiling_train_seed5.npz", False)]
    assert _ceiling_runs(7, None, None, tmp_path) == [(7, tmp_path / "ceiling_train.npz", False)]
    assert _ceiling_runs(7, None, tmp_path / "a.npz", tmp_path) == [(7, tmp_path / "a.npz", True)]
    files = [tmp_path / "a.npz", tmp_path / "b.npz"]
    for f in files:
        f.write_bytes(b"")
    with pytest.raises(SystemExit, match=r"--ceiling-data has 2 file\(s\) but --ceiling-seeds \[0\] has 1"):
        main(["--out", str(tmp_path / "x"), "--ceiling-data", *map(str, files)])
    with pytest.raises(SystemExit, match=r"--ceiling-seeds \[1, 1\]: allowed distinct integers >= 0"):
        main(["--out", str(tmp_path / "x"), "--ceiling-seeds", "1", "1"])
    with pytest.raises(SystemExit, match=r"--ceiling-data .*missing.npz: no such file"):
        main(["--out", str(tmp_path / "x"), "--ceiling-data", str(tmp_path / "missing.npz")])
    assert not (tmp_path / "x").exists()


def test_a_saved_ceiling_set_made_under_another_plant_contact_is_refused(tmp_path):
    """A set made with ``world.plant.on_contact=stop`` lacks the records ``stuck`` adds: refused before any compute,
    naming both settings; a set that records nothing is refused too, and so is one of another numerics revision."""

    import numpy as np

    from active.ladder import check_ceiling_data
    from sim.engine.config import NUMERICS_REVISION

    stop_set = tmp_path / "stop.npz"  # the tags of a set made under stop (its transitions do not matter here)
    np.savez(stop_set, plant_on_contact=np.array("stop"), numerics_revision=np.array(NUMERICS_REVISION))
    with pytest.raises(
        SystemExit,
        match=r"made with world.plant.on_contact=stop, but the run has "
        r"world.plant.on_contact=stuck",
    ):
        main(["--out", str(tmp_path / "x"), "--rungs", "ceiling", "--ceiling-data", str(stop_set)])
    assert not (tmp_path / "x").exists()
    check_ceiling_data(stop_set, "stop")
    untagged = tmp_path / "untagged.npz"
    np.savez(untagged, category=np.array(["other"]), numerics_revision=np.array(NUMERICS_REVISION))
    with pytest.raises(ValueError, match=r"records no world.plant.on_contact .*remake it"):
        check_ceiling_data(untagged, "stuck")
    older = tmp_path / "older.npz"  # simulated with the direct 2D transfers (revision 1 records no revision)
    np.savez(older, plant_on_contact=np.array("stuck"))
    with pytest.raises(ValueError, match=r"numerics revision 1, this code's is 2 .*remake it"):
        check_ceiling_data(older, "stuck")
