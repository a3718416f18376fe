"""Files of a run directory: atomic writes (through :mod:`safeio`) and reads with clear errors.

A run killed at any moment leaves either the old or the new file, never half of one; a file that is
nevertheless unreadable (a disk problem, a copy cut short) is reported with its path and what to do
instead of a raw unpickling or zip-reader error.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import safeio


class RunFileError(RuntimeError):
    """A file in a run directory cannot be used; the message names it and says what to do."""


def as_json(obj: Any) -> Any:
    """``obj`` as JSON would store it (plain dicts, lists and scalars; anything else as ``str``): what a
    run's ``config.json`` holds, so configs compare and hash the same before and after a round trip."""
    return json.loads(json.dumps(obj, default=str))


def write_json(path: Path, obj: Any) -> None:
    safeio.write_json(path, obj, indent=1)


def write_csv(path: Path, rows: Sequence[Mapping[str, Any]], fields: Sequence[str] | None = None) -> None:
    fields = list(fields or (rows[0].keys() if rows else []))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore")
    w.writeheader()
    w.writerows(rows)
    safeio.write_text(path, buf.getvalue())


def read_csv(path: Path) -> list[dict[str, str]]:
    """The rows of a CSV this code wrote; a file that is not one (undecodable bytes, a row cut short or with extra
    fields) is a :class:`RunFileError` naming the file and the line, never rows silently lost or shifted."""
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            rows = list(reader)
    except (UnicodeDecodeError, csv.Error) as e:
        raise RunFileError(f"{path} is not a readable CSV ({type(e).__name__}: {str(e)[:160]})") from None
    for k, row in enumerate(rows):
        if None in row or None in row.values():
            raise RunFileError(
                f"{path} line {k + 2} has {'more' if None in row else 'fewer'} fields than its header "
                f"({len(reader.fieldnames or [])}): the file is truncated or damaged"
            )
    return rows


def save_torch(path: Path, obj: Any) -> None:
    safeio.save_torch(path, obj)


def load_torch(path: Path, fix: str = "delete it and run the same command again") -> Any:
    """``torch.load`` of a file this runner wrote; any failure names the file and says ``fix``."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise RunFileError(f"{path} does not exist; {fix}")
    try:
        return torch.load(path, weights_only=False, map_location="cpu")
    except Exception as e:  # noqa: BLE001 - every reader failure means the same thing: unusable file
        raise RunFileError(f"{path} is unreadable ({describe_load_error(e)}); {fix}") from None


CHECKED_FORMAT = "active-mde/checked-torch"


def save_checked(path: Path, obj: Any) -> str:
    """Write ``obj`` (``torch.save``) with the sha256 of its bytes inside the same file, atomically; returns the
    digest. torch does not check its zip's CRC-32, so damage inside a tensor's bytes would load silently; a
    checked file refuses it (:func:`load_checked`)."""
    import torch

    buf = io.BytesIO()
    torch.save(obj, buf)
    data = buf.getvalue()
    digest = hashlib.sha256(data).hexdigest()
    safeio.save_torch(path, {"format": CHECKED_FORMAT, "sha256": digest, "data": data})
    return digest


def load_checked(path: Path, fix: str = "delete it and run the same command again") -> Any:
    """Read a file of :func:`save_checked`, verifying its checksum; any failure names the file and says ``fix``."""
    import torch

    wrapper = load_torch(path, fix)
    if not (isinstance(wrapper, dict) and wrapper.get("format") == CHECKED_FORMAT and "data" in wrapper):
        raise RunFileError(f"{path} is not a checksummed file of this code (written by another run format?); {fix}")
    data = wrapper["data"]
    if hashlib.sha256(data).hexdigest() != wrapper.get("sha256"):
        raise RunFileError(f"{path} is damaged (its content does not match the checksum stored with it); {fix}")
    try:
        return torch.load(io.BytesIO(data), weights_only=False, map_location="cpu")
    except Exception as e:  # noqa: BLE001
        raise RunFileError(f"{path} is unreadable ({describe_load_error(e)}); {fix}") from None


def file_sha256(path: Path) -> str:
    """The sha256 of a file's bytes (recorded for files another module writes, e.g. MDE checkpoints)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def describe_load_error(e: BaseException) -> str:
    """A short reason for a failed ``torch.load``, without torch's advice to load unsafely."""
    first = (str(e).strip().splitlines() or [""])[0]
    if "weights_only" in str(e) or type(e).__name__ == "UnpicklingError":
        return f"not a torch file written by this code ({type(e).__name__})"
    if isinstance(e, OSError) or "zip" in first.lower() or "central directory" in first:
        return f"truncated or damaged ({type(e).__name__}: {first[:160]})"
    return f"{type(e).__name__}: {first[:160]}"


def concat_rows(groups: Iterable[Sequence[Mapping[str, Any]]]) -> list[dict[str, Any]]:
    return [dict(r) for g in groups for r in g]
