"""A run's identity: the part of its configuration that decides its results, and the run format.

A run directory may only be extended by the configuration that wrote it. Its ``state.pt`` files,
calibration set and model-alone rows record :func:`config_digest`; a rerun with another digest is
refused, naming the fields that differ (:func:`config_differences`). The digest covers
:data:`RUN_FORMAT_VERSION` and the solver's ``NUMERICS_REVISION``, so files written by another version of the
run format, or simulated with other arithmetic, are never reused.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any, Mapping

from sim.engine.config import NUMERICS_REVISION

from .io import as_json

#: the format of a run directory's files; this code reads its own version and refuses any other
RUN_FORMAT = "active-mde/run"
RUN_FORMAT_VERSION = 2


def comparable_config(cfg: Mapping[str, Any]) -> dict:
    """The part of a config that determines results: not run length, logging, progress bars, nor
    where the dynamics cache lives (moving the cache must not make a finished run unresumable), nor
    the specs of methods the run does not execute."""
    c = as_json(cfg)
    specs = c.pop("methods", None)
    method = c.get("method", "all")
    used = list(c.get("experiment", {}).get("methods", [])) if method == "all" else [method]
    if isinstance(specs, dict):
        c["methods"] = {m: specs[m] for m in used if m in specs}
    for k in ("iterations", "methods"):
        c.get("experiment", {}).pop(k, None)
    for k in ("cache_root", "progress"):
        c.get("dynamics", {}).pop(k, None)
    for k in ("wandb", "progress", "method", "runner", "seeds"):  # runner, seeds: how runs are carried out
        c.pop(k, None)
    c.get("planner", {}).pop("workers", None)  # where plans are computed, not what they are
    c["run_format_version"] = RUN_FORMAT_VERSION
    c["sim_numerics_revision"] = NUMERICS_REVISION  # the solver's rounding: another revision's pours differ
    return c


def config_digest(cfg: Mapping[str, Any]) -> str:
    """Hash of everything that determines results (:func:`comparable_config`)."""
    return hashlib.sha256(json.dumps(comparable_config(cfg), sort_keys=True).encode()).hexdigest()[:16]


def config_differences(old: Mapping[str, Any] | None, new: Mapping[str, Any], limit: int = 12) -> list[str]:
    """``key: old -> new`` for the result-relevant fields that differ (dotted keys)."""
    if old is None:
        return []
    a, b = flatten(comparable_config(old)), flatten(comparable_config(new))
    diffs = [
        f"{k}: {a.get(k, '(absent)')!r} -> {b.get(k, '(absent)')!r}"
        for k in sorted(set(a) | set(b))
        if a.get(k, "(absent)") != b.get(k, "(absent)")
    ]
    return diffs[:limit] + ([f"... and {len(diffs) - limit} more"] if len(diffs) > limit else [])


def flatten(d: Any, prefix: str = "") -> dict[str, Any]:
    """A nested mapping as ``{dotted.key: leaf}``."""
    if not isinstance(d, dict):
        return {prefix: d}
    out: dict[str, Any] = {}
    for k, v in d.items():
        out.update(flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    return out
