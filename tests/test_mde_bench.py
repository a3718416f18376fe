"""Smoke test of the MDE benchmark command (tiny sizes; the real figures come from the command)."""

from __future__ import annotations

import json

from benchmarks.mde import format_table, main, run


def test_bench_runs_and_writes_json(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["--sizes", "25", "40", "--batch", "64", "--d", "3", "--threads", "1", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert [r["n"] for r in result["fit"]] == [25, 40]
    assert all(r["fit_s"] > 0 for r in result["fit"])
    expected = {(1, "float32"), (64, "float32"), (1, "float64"), (64, "float64")}
    assert {(r["batch"], r["dtype"]) for r in result["predict"]} == expected
    assert result["float32_vs_float64"]["max_rel_std_diff"] < 1e-2
    assert "fit [s]" in capsys.readouterr().out


def test_format_table_reports_targets():
    result = run(sizes=(30,), batch=16, d=2, num_threads=1)
    text = format_table(result)
    assert "n_train" in text and "float32 vs float64" in text
