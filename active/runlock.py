"""One writer per run directory: ``<run dir>/run.lock`` names the owner (pid, host, start, command).

Why: two runs started into one directory (a sweep with a fixed ``hydra.run.dir``, a manual rerun
while a SLURM job still runs) would both exit 0 and leave whichever finished last. The lock is a
POSIX record lock (``fcntl.lockf``) on ``run.lock``: the kernel (or, on NFS, the lock manager)
releases it when the owner dies, however it dies, so a killed run's directory is taken over by the
next run without any manual step, while a living owner's is refused with a message that names it.
``lockf`` rather than ``flock``: POSIX locks are the kind network file systems implement, and a
child process the owner forks does not inherit them (it cannot keep a dead owner's lock alive).

The file itself is never deleted (deleting it while another process waits on it would let two
processes lock two different files); it is emptied on release. On a file system without locks the
record alone decides: a live pid on this host (``os.kill(pid, 0)``) or a record from another host
refuses; a dead pid on this host is taken over.
"""

from __future__ import annotations

import errno
import fcntl
import json
import logging
import os
import socket
import sys
import time
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)
LOCK_NAME = "run.lock"
#: lock files held by this process -> their record (POSIX locks do not exclude their own process, and
#: closing any descriptor of a locked file drops the lock, so this process must never reopen it)
_HELD: dict[str, dict[str, Any]] = {}


class RunDirectoryError(RuntimeError):
    """The run directory cannot be used as asked; the message says why and what to do."""


class RunLockedError(RunDirectoryError):
    """Another run owns the directory; the message names it and what to do."""


class RunLock:
    """Exclusive ownership of a run directory for a ``with`` block (or ``acquire`` / ``release``)."""

    def __init__(self, folder: str | os.PathLike):
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self._fd: int | None = None
        self.previous: dict[str, Any] | None = None  # the record of a dead owner that was taken over

    def __enter__(self) -> "RunLock":
        self.acquire()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.release()

    def acquire(self) -> None:
        """Take the lock or raise :class:`RunLockedError`; a dead owner's lock is taken over (logged)."""
        key = os.path.realpath(self.path)
        if key in _HELD:  # checked before opening: closing a descriptor would drop our own lock
            raise RunLockedError(
                f"the run directory {self.folder} is already in use by a run of this process "
                f"(pid {os.getpid()}); use another output directory"
            )
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o666)
        except OSError as e:
            raise RunDirectoryError(
                f"cannot create the run lock {self.path} ({e.strerror or e}): the output "
                f"directory is not writable; fix its permissions or choose another one "
                f"(hydra.run.dir=...)"
            ) from None
        try:
            fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            owner = _read_record(fd)
            if e.errno in (errno.EACCES, errno.EAGAIN):
                os.close(fd)
                raise RunLockedError(_refusal(self.folder, self.path, owner)) from None
            # no locks on this file system (ENOLCK, EOPNOTSUPP...): the pid record alone decides
            mine = owner and owner.get("pid") == os.getpid() and owner.get("host") == socket.gethostname()
            if owner and not mine and _alive(owner) is not False:
                os.close(fd)
                raise RunLockedError(_refusal(self.folder, self.path, owner, locks=False)) from None
            log.warning(
                "%s: the file system does not support locks (%s); relying on the pid record in %s",
                self.folder,
                e.strerror or e,
                self.path,
            )
        previous = _read_record(fd)
        if previous:
            self.previous = previous
            log.warning(
                "taking over %s from %s, which ended without releasing it (killed?); resuming its work",
                self.path,
                _describe(previous),
            )
        record = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started": time.strftime("%Y-%m-%d %H:%M:%S"),
            "command": " ".join(sys.argv)[:500],
        }
        data = (json.dumps(record) + "\n").encode()
        os.ftruncate(fd, 0)
        os.pwrite(fd, data, 0)
        os.fsync(fd)
        self._fd = fd
        _HELD[key] = record

    def release(self) -> None:
        """Empty the record and unlock (the file stays: see the module docstring)."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        _HELD.pop(os.path.realpath(self.path), None)
        try:
            os.ftruncate(fd, 0)
            os.fsync(fd)
        except OSError:
            pass
        finally:
            try:
                fcntl.lockf(fd, fcntl.LOCK_UN)
            finally:
                os.close(fd)


def read_owner(folder: str | os.PathLike) -> dict[str, Any] | None:
    """The record in ``<folder>/run.lock`` (None when free or absent); for messages and tests."""
    path = Path(folder) / LOCK_NAME
    key = os.path.realpath(path)
    if key in _HELD:  # ours: reopening the file would drop our own lock when closed
        return dict(_HELD[key])
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        return _read_record(fd)
    finally:
        os.close(fd)


def _read_record(fd: int) -> dict[str, Any] | None:
    try:
        raw = os.pread(fd, 4096, 0)
    except OSError:
        return None
    if not raw.strip():
        return None
    try:
        rec = json.loads(raw.decode(errors="replace"))
        return rec if isinstance(rec, dict) else {"raw": raw[:200].decode(errors="replace")}
    except json.JSONDecodeError:
        return {"raw": raw[:200].decode(errors="replace")}


def _alive(owner: dict[str, Any]) -> bool | None:
    """True / False for a pid on this host; None when it cannot be told (another host, no pid)."""
    if owner.get("host") != socket.gethostname() or not isinstance(owner.get("pid"), int):
        return None
    try:
        os.kill(owner["pid"], 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by another user
        return True
    return True


def _describe(owner: dict[str, Any] | None) -> str:
    if not owner:
        return "another process (its record is not written yet)"
    if "pid" not in owner:
        return f"an unknown owner (record {owner.get('raw', '')!r})"
    return f"pid {owner['pid']} on host {owner.get('host', '?')}, started {owner.get('started', '?')}" + (
        f" ({owner['command']})" if owner.get("command") else ""
    )


def _refusal(folder: Path, path: Path, owner: dict[str, Any] | None, locks: bool = True) -> str:
    gone = (
        "if that run is gone (its node crashed), its lock expires by itself within minutes"
        if locks
        else f"if that run has ended, delete {path}"
    )
    return (
        f"the run directory {folder} is in use by another run: {_describe(owner)}. Two runs writing one "
        f"directory would overwrite each other's results, so this one stops before doing anything. Wait for "
        f"it to finish, or write to another directory (hydra.run.dir=... or another seed / method); {gone}."
    )
