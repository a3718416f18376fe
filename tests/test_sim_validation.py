"""Physics validation cases (the same functions `python -m benchmarks.validate` runs)."""

import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks import validate
from benchmarks.validate import (
    DAM_BREAK_TOLERANCE,
    dam_break_error,
    load_martin_moyce,
    run_dam_break,
    run_leak,
    run_rest,
    world_physics,
)

#: the default world's liquid model (ppc 9, ghost wall mass, ...): the water the experiment runs
WORLD = world_physics("default")

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "martin_moyce_1952_surge_front.csv"


def test_packaged_reference_data_matches_shared_copy():
    data = load_martin_moyce()
    assert data.shape == (16, 2) and data[0, 1] == 1.0
    if SHARED.exists():
        shared = np.loadtxt(SHARED, delimiter=",", comments="#", skiprows=4)
        np.testing.assert_array_equal(data, shared)


def test_dam_break_front_matches_martin_moyce():
    res = run_dam_break(dx=0.01)
    assert not res["unstable"]
    err = dam_break_error(res)
    assert err < DAM_BREAK_TOLERANCE, f"mean relative front error {err:.3f}"
    front = np.asarray(res["front_x"])
    assert np.all(np.diff(front) >= -0.2 * 0.01)  # the surge front only advances (to within a fifth of a cell)
    height = np.asarray(res["column_height"])
    assert height[-1] < 0.6 * height[0]  # the column collapses at the wall


def test_dam_break_error_metric_rejects_a_wrong_front():
    data = load_martin_moyce()
    a, g = 0.05715, 9.81
    t = np.linspace(0, 0.2, 50)
    T = t * np.sqrt(2 * g / a)
    exact = {"t": t, "front_x": np.interp(T, data[:, 0], data[:, 1]) * a, "a": a, "g": g}
    slow = dict(exact, front_x=exact["front_x"] * 0.7)
    assert dam_break_error(exact) < 0.01
    assert dam_break_error(slow) > DAM_BREAK_TOLERANCE


def test_dam_break_command_writes_json_and_png(tmp_path):
    """The command runs the default world's liquid model (the test above: the solver's defaults)."""
    validate.main(["dam-break", "--out", str(tmp_path), "--dx", "0.01", "--resolutions", "0.01"])
    out = json.loads((tmp_path / "dam_break.json").read_text())
    assert out["physics"] == WORLD and out["mean_relative_error"] < DAM_BREAK_TOLERANCE
    for key in ("t", "front_x", "column_height", "a", "g", "resolution_study"):
        assert key in out
    assert len(out["t"]) == len(out["front_x"]) == len(out["column_height"])
    assert (tmp_path / "dam_break.png").stat().st_size > 10_000


@pytest.mark.parametrize("physics", [None, WORLD], ids=["solver_defaults", "default_world"])
def test_water_at_rest_stays_put_and_flat(physics):
    res = run_rest(duration=2.0, physics=physics)
    dx = res["dx"]
    assert res["particles_end"] == res["particles_start"] and not res["nan"]
    assert res["fraction_in_cup"] == 1.0
    assert res["com_drift_x_m"] < 0.05 * dx  # no sideways drift
    assert res["com_drift_m"] < 0.5 * dx  # settling under its own weight, under half a cell
    assert res["rms_speed_m_s"] < 0.01
    assert res["surface_std_m"] < 0.25 * dx  # the free surface is flat to a quarter cell


def test_cup_held_still_keeps_water():
    res = run_leak("still", duration=2.0, physics=WORLD)
    assert res["fraction_kept"] > 0.99 and not res["unstable"]


def test_cup_carried_at_fastest_move_speed_keeps_water():
    res = run_leak("carried", peak_speed=0.3, physics=WORLD)
    assert res["fraction_kept"] > 0.98 and not res["unstable"]


def test_leak_mode_is_validated():
    with pytest.raises(ValueError, match="allowed 'still' or 'carried'"):
        run_leak("shaken")
