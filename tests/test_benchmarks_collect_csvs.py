"""benchmarks/collect_csvs.py: runs made at different times land in one committed tree that active.report reads."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from benchmarks.collect_csvs import collect


def _run(root: Path, seed: int, method: str, digest: str = "aaaa", success: str = "0.5") -> Path:
    """A run directory of one seed and method, as active.run lays it out (CSVs only, plus a tensor to leave behind)."""
    sdir = root / f"seed{seed}"
    mdir = sdir / method
    mdir.mkdir(parents=True)
    (mdir / "results.csv").write_text(f"method,seed,iteration,test_success\n{method},{seed},1,{success}\n")
    (mdir / "tests.csv").write_text(f"method,seed,iteration,problem\n{method},{seed},1,0\n")
    (mdir / "dataset.pt").write_bytes(b"\0")
    (sdir / "model_only.csv").write_text(f"seed,problem,found,digest\n{seed},0,True,{digest}\n")
    (sdir / "config.json").write_text(f'{{"digest": "{digest}"}}')
    return root


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def test_collects_csvs_of_several_runs_and_renames_a_method(tmp_path):
    a = _run(tmp_path / "a", 0, "random_plan")
    b = _run(tmp_path / "b", 0, "active_balanced", digest="bbbb")  # same seed, another run: model_only rows agree
    dest = tmp_path / "tree"
    assert collect(dest, [a], {}) == 4
    assert collect(dest, [b / "seed0" / "active_balanced"], {"active_balanced": "active_straddle"}) == 3
    assert sorted(p.name for p in (dest / "seed0").iterdir()) == ["active_straddle", "model_only.csv", "random_plan"]
    assert not list(dest.rglob("*.pt"))
    assert _rows(dest / "seed0" / "active_straddle" / "results.csv")[0]["method"] == "active_straddle"
    assert _rows(dest / "seed0" / "active_straddle" / "tests.csv")[0]["method"] == "active_straddle"
    assert (dest / "seed0" / "active_straddle" / "config.json").read_text() == '{"digest": "bbbb"}'
    assert collect(dest, [a], {}) == 0  # idempotent


def test_two_sources_for_one_method_and_seed_is_an_error(tmp_path):
    a = _run(tmp_path / "a", 1, "random_plan", success="0.5")
    b = _run(tmp_path / "b", 1, "random_plan", success="0.6")
    collect(tmp_path / "tree", [a], {})
    with pytest.raises(SystemExit, match="results.csv exists with other contents"):
        collect(tmp_path / "tree", [b], {})


def test_a_source_without_results_is_an_error(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit, match="no results.csv"):
        collect(tmp_path / "tree", [tmp_path / "empty"], {})
