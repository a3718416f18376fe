"""The project's one atomic file writer (dependency-free: ``sim`` and ``mde`` may import it too).

Why one writer: a run killed at any moment (SIGKILL, a SLURM time limit, a crashed node) must leave
every file either old or new, never half-written; results must survive a power loss once the run
says they are saved; and a cluster user's group must be able to read them. So every write here

* goes to a temporary file beside the target (``.<name>.<pid>.<random>.tmp``, same file system),
* is flushed and ``fsync``-ed, then renamed over the target with ``os.replace`` (atomic), and the
  directory entry is ``fsync``-ed too (the rename itself survives a crash),
* creates the file with mode ``0o666`` minus the process umask, like ``open()`` does (``mkstemp``
  would give ``0o600``: unreadable for the group).

A writer killed between creating and renaming its temporary file leaves it behind; whoever owns the
folder (and holds its lock) removes such orphans with :func:`remove_orphans`.
"""

from __future__ import annotations

import json
import os
import secrets
from pathlib import Path
from typing import IO, Any, Callable, Union

__all__ = [
    "atomic_write",
    "write_text",
    "write_json",
    "save_torch",
    "save_figure",
    "adopt",
    "json_default",
    "remove_orphans",
    "current_umask",
    "fsync_dir",
    "TMP_SUFFIX",
]

TMP_SUFFIX = ".tmp"
#: what :func:`atomic_write` accepts: the bytes / text to write, or a function writing to a binary file
Payload = Union[bytes, bytearray, memoryview, str, Callable[[IO[bytes]], Any]]


def atomic_write(path: str | os.PathLike, data: Payload, *, encoding: str = "utf-8") -> Path:
    """Write ``data`` to ``path`` atomically and durably, with the umask's permissions.

    ``data`` may be a callable ``write(fileobj)`` (e.g. ``lambda f: torch.save(obj, f)``), so large
    payloads stream to disk instead of being built in memory first. Returns ``path``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}{TMP_SUFFIX}")
    # O_EXCL: never follow or reuse someone else's file; 0o666: the kernel applies the umask
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            if callable(data):
                data(f)
            else:
                f.write(data.encode(encoding) if isinstance(data, str) else data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    fsync_dir(path.parent)
    return path


def write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Atomic text file (see :func:`atomic_write`)."""
    return atomic_write(path, text, encoding=encoding)


def write_json(path: str | os.PathLike, obj: Any, indent: int | None = 1, **dumps_kw: Any) -> Path:
    """Atomic JSON file; numpy / torch values, tuples, sets and paths are converted (:func:`json_default`)."""
    dumps_kw.setdefault("default", json_default)
    return atomic_write(path, json.dumps(obj, indent=indent, **dumps_kw) + "\n")


def save_torch(path: str | os.PathLike, obj: Any) -> Path:
    """Atomic ``torch.save`` (torch is imported only here, so this module stays dependency-free)."""
    import torch

    return atomic_write(path, lambda f: torch.save(obj, f))


def save_figure(fig: Any, path: str | os.PathLike, **savefig_kw: Any) -> Path:
    """Atomic ``fig.savefig``; the format comes from the file name's suffix unless given."""
    path = Path(path)
    savefig_kw.setdefault("format", path.suffix.lstrip(".") or None)
    return atomic_write(path, lambda f: fig.savefig(f, **savefig_kw))


def adopt(path: str | os.PathLike) -> Path:
    """Give a file that another writer already renamed into place this module's guarantees.

    For writers we cannot change (e.g. one that uses ``mkstemp``: mode 0600, no fsync): sets the
    umask's permissions and flushes the file and its directory entry to disk.
    """
    path = Path(path)
    os.chmod(path, 0o666 & ~current_umask())
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    fsync_dir(path.parent)
    return path


def fsync_dir(folder: str | os.PathLike) -> None:
    """Flush a directory's entries (a rename is only durable once its directory is); best effort."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:  # some file systems cannot fsync a directory (EINVAL): nothing more to do
        pass
    finally:
        os.close(fd)


def current_umask() -> int:
    """The process umask, read without changing it where the OS allows (Linux: /proc/self/status)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)  # elsewhere: set and restore at once
    os.umask(mask)
    return mask


def remove_orphans(folder: str | os.PathLike) -> list[Path]:
    """Delete temporary files (``.<name>...tmp``) that killed writers left in ``folder`` (not recursive).

    Call it only while holding the folder's lock: a live writer's temporary file looks the same.
    Returns the removed paths.
    """
    removed = []
    try:
        entries = list(os.scandir(folder))
    except FileNotFoundError:
        return removed
    for e in entries:
        if e.name.startswith(".") and e.name.endswith(TMP_SUFFIX) and e.is_file(follow_symlinks=False):
            try:
                os.unlink(e.path)
                removed.append(Path(e.path))
            except FileNotFoundError:
                pass
    return removed


def json_default(o: Any) -> Any:
    """JSON for values ``json`` does not know: numpy / torch arrays and scalars, tuples, sets, paths."""
    if isinstance(o, (tuple, set, frozenset)):
        return list(o)
    if isinstance(o, os.PathLike):
        return os.fspath(o)
    if hasattr(o, "tolist"):  # numpy arrays and scalars, torch tensors
        return o.tolist()
    if hasattr(o, "item"):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
