"""Collect the CSVs of finished runs into one tree that can be committed (``results/quick/csv``, ``results/paper/csv``).

A run directory holds tensors (datasets, MDE states) next to its CSVs; ``active.report`` needs only the CSVs. This
copies, for each seed, ``model_only.csv`` (the same in every run of that seed) and, for each method, ``results.csv``,
``categories.csv``, ``calibration.csv``, ``tests.csv`` and the resolved ``config.json`` of the run it came from
into ``DEST/seedN/METHOD/``. Sources may be run
directories (holding ``seedN/``), seed directories or single method directories, so that runs made at different
times (seeds 0-5 in one job, 6-11 in another) land side by side. ``--rename OLD=NEW`` files a method under another
name (the ``method`` column is rewritten too): for runs of a method made under another method's name, e.g. runs
of active_balanced with ``acquisition=straddle``, the method ``configs/methods`` calls ``active_straddle``.

    python benchmarks/collect_csvs.py results/quick/csv RUN1 RUN2/seed6/random_plan \
        --rename active_balanced=active_straddle

A file already in DEST with other contents is an error (two sources for one seed and method), never overwritten.
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
from pathlib import Path

SEED_FILES = ("model_only.csv",)
METHOD_FILES = ("results.csv", "categories.csv", "calibration.csv", "tests.csv")


def _renamed(text: str, rename: dict[str, str]) -> str:
    """The CSV ``text`` with its ``method`` column mapped through ``rename``."""
    rows = list(csv.DictReader(io.StringIO(text)))
    if not rename or not rows or "method" not in rows[0]:
        return text
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    for row in rows:
        row["method"] = rename.get(row["method"], row["method"])
        writer.writerow(row)
    return out.getvalue()


def _without_digest(text: str) -> list[dict[str, str]]:
    """The CSV's rows less the ``digest`` column (the run config's hash, which names overrides that did not touch the
    model alone: two runs of one seed give the same ``model_only.csv`` rows under different digests)."""
    return [{k: v for k, v in row.items() if k != "digest"} for row in csv.DictReader(io.StringIO(text))]


def _put(text: str, dest: Path) -> bool:
    """Write ``text`` to ``dest`` unless it is there already; a different file there is an error."""
    if dest.exists():
        old = dest.read_text()
        same = old == text or (dest.name == "model_only.csv" and _without_digest(old) == _without_digest(text))
        if not same:
            raise SystemExit(f"collect_csvs: {dest} exists with other contents (two sources for one seed and method?)")
        return False
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(text)
    return True


def method_dirs(source: Path) -> list[Path]:
    """The method directories (holding ``results.csv``) under a run, seed or method directory."""
    if (source / "results.csv").is_file():
        return [source]
    found = [p.parent for p in source.glob("*/results.csv")] + [p.parent for p in source.glob("seed*/*/results.csv")]
    if not found:
        raise SystemExit(f"collect_csvs: no results.csv in or under {source} (a run, seed or method directory)")
    return sorted(set(found))


def collect(dest: Path, sources: list[Path], rename: dict[str, str]) -> int:
    """Copy the CSVs of ``sources`` into ``dest``; the number of files written."""
    written = 0
    for source in sources:
        for mdir in method_dirs(source):
            seed_dir = mdir.parent
            method = rename.get(mdir.name, mdir.name)
            for name in METHOD_FILES:
                if (mdir / name).is_file():
                    written += _put(_renamed((mdir / name).read_text(), rename), dest / seed_dir.name / method / name)
            if (seed_dir / "config.json").is_file():  # the resolved config of the run this method came from
                written += _put((seed_dir / "config.json").read_text(), dest / seed_dir.name / method / "config.json")
            for name in SEED_FILES:
                if (seed_dir / name).is_file():
                    written += _put((seed_dir / name).read_text(), dest / seed_dir.name / name)
    return written


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dest", type=Path, help="the tree to fill (DEST/seedN/METHOD/*.csv)")
    parser.add_argument("sources", type=Path, nargs="+", help="run, seed or method directories")
    parser.add_argument(
        "--rename",
        action="append",
        default=[],
        metavar="OLD=NEW",
        help="file method OLD under NEW, for every source of this call (repeatable)",
    )
    args = parser.parse_args(argv)
    rename = {}
    for item in args.rename:
        old, sep, new = item.partition("=")
        if not sep or not old or not new:
            parser.error(f"--rename takes OLD=NEW, got {item!r}")
        rename[old] = new
    missing = [str(s) for s in args.sources if not s.exists()]
    if missing:
        parser.error(f"no such source: {', '.join(missing)}")
    n = collect(args.dest, args.sources, rename)
    print(f"{n} files written under {args.dest}", file=sys.stderr)


if __name__ == "__main__":
    main()
