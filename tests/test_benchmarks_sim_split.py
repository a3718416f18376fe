"""The split-substep benchmark: both paths on the same scene give the same bits (timing is the benchmark's job)."""

import json

import pytest

from benchmarks.sim_split import main


def test_one_substep_count_per_spacing_is_required(capsys):
    with pytest.raises(SystemExit, match="2"):
        main(["--dx", "0.01", "0.005", "--substeps", "10"])
    assert "--substeps: give one count per --dx (2), got 1" in capsys.readouterr().err


@pytest.mark.slow  # compiles two 3D solvers
def test_both_paths_run_the_same_scene_to_the_same_bits(tmp_path):
    out = tmp_path / "split.json"
    res = main(["--dx", "0.02", "--substeps", "20", "--rounds", "1", "--out", str(out)])
    (row,) = res["rows"]
    assert row["particles"] > 0 and row["bit_identical"]
    assert set(row["particle_substeps_per_s"]) == {"one_task", "split", "direct"}
    assert row["direct_max_position_difference_m"] > 0  # the direct transfers are another rounding of the same flow
    assert json.loads(out.read_text())["rows"][0]["bit_identical"]
