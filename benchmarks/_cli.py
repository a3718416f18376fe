"""The end every benchmark CLI shares: show the table, optionally save the full result as JSON."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import safeio


def report(table: str, result: Any, out: Path | None) -> None:
    """Print ``table``, write ``result`` to ``out`` as JSON if given, and flush (output may be piped to a log)."""
    print(table)
    if out is not None:
        safeio.write_json(out, result, indent=2, default=str)
        print(f"wrote {out}")
    sys.stdout.flush()
