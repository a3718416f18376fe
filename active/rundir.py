"""What a run may reuse from its directory, checked before any compute.

A run directory holds results only one configuration may extend: per method ``state.pt`` (with the
run format version and the digest of the configuration that wrote it, :mod:`active.identity`),
``mde_iterNNN.pt`` checkpoints, and the shared ``calibration_set.pt``. Everything reused is checked
against the configuration that made it; a mismatch is refused (results) or rebuilt (the calibration
set, a deterministic function of the configuration), never used silently; ``config.json`` is
rewritten only after the directory was accepted, so a refused rerun leaves the directory describing
its own results.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any, Mapping

import torch

import safeio

from .identity import RUN_FORMAT, RUN_FORMAT_VERSION, config_differences, config_digest
from .io import CHECKED_FORMAT, RunFileError, describe_load_error, file_sha256, load_checked, load_torch
from .runlock import RunDirectoryError

log = logging.getLogger(__name__)

#: files a method directory holds besides state.pt (named in messages about what survives)
METHOD_FILES = ("results.csv", "categories.csv", "calibration.csv", "tests.csv", "dataset.pt", "mde_iter*.pt")


# ------------------------------------------------------------------ the directory
def read_recorded_config(out: Path) -> dict | None:
    """The directory's ``config.json`` (None if absent; unreadable: warned and None, it is rewritten)."""
    path = out / "config.json"
    if not path.exists():
        return None
    try:
        rec = json.loads(path.read_text())
        return rec if isinstance(rec, dict) else None
    except (OSError, ValueError) as e:
        log.warning(
            "%s is unreadable (%s); the state files decide whether this directory can be resumed, and "
            "it is rewritten once they have been checked",
            path,
            e,
        )
        return None


def state_fix(path: Path) -> str:
    """What to do about an unusable ``<method>/state.pt``, and what survives it."""
    kept = sorted({p.name for pat in METHOD_FILES for p in path.parent.glob(pat)})
    kept_txt = f"{', '.join(kept)} beside it are intact and kept" if kept else "nothing else of this method was saved"
    return (
        f"{kept_txt}, as are the other methods of {path.parent.parent} and its calibration set, but this method "
        f"cannot resume without state.pt. Restore it from a backup, or delete it and run the same command again "
        f"to redo this method from iteration 1 (its CSVs, dataset.pt and checkpoints are then rewritten: copy "
        f"them elsewhere first to keep them)"
    )


def load_state(path: Path) -> dict:
    """A method's ``state.pt``: checksum verified, run format version checked (errors name the file, what survives
    and what to do)."""
    fix = state_fix(path)
    raw = load_torch(path, fix=fix)
    st = load_checked(path, fix) if isinstance(raw, dict) and raw.get("format") == CHECKED_FORMAT else raw
    check_state_format(st, path)
    return st


def check_state_format(st: Any, path: Path) -> None:
    """Refuse a ``state.pt`` of another run format version, naming both versions and how to rerun."""
    if not isinstance(st, dict) or "digest" not in st or "completed" not in st:
        raise RunFileError(f"{path} is not a state file of this runner; {state_fix(path)}")
    version = st.get("version", 1) if st.get("format", RUN_FORMAT) == RUN_FORMAT else st.get("format")
    if version != RUN_FORMAT_VERSION:
        raise RunFileError(
            f"{path} has run format version {version}; this code reads version {RUN_FORMAT_VERSION}. Its results "
            f"(the CSVs beside it) stay readable by active.report, but the run cannot be extended: rerun the "
            f"experiment into a new directory (hydra.run.dir=...), or resume it with the release that wrote it"
        )


def check_run_directory(out: Path, cfg: Mapping[str, Any]) -> bool:
    """Refuse, before any compute, a directory holding results of another configuration or run format.

    Reads every ``*/state.pt`` (errors name the file and what survives), checks its format version,
    its digest, that it holds no more iterations than ``experiment.iterations`` (a shorter run is no
    rewrite of a longer one) and that its MDE checkpoint is readable. Returns whether any method has resumable
    state. Leftovers of a run of another configuration that never completed an iteration are not
    results: such a directory is accepted (the calibration set is checked on its own).
    """
    recorded = read_recorded_config(out)
    digest = config_digest(cfg)
    iterations = int(cfg.get("experiment", {}).get("iterations", 0))
    mismatched, longer, resumable = [], [], False
    for state_path in sorted(out.glob("*/state.pt")):
        st = load_state(state_path)
        if st["digest"] != digest:
            mismatched.append(f"{state_path.parent.name} ({st['completed']} iterations)")
            continue
        resumable = True
        if st["completed"] > iterations > 0:
            longer.append(f"{state_path.parent.name} ({st['completed']} iterations)")
        if st.get("mde_path"):
            check_checkpoint(state_path.parent / st["mde_path"], st.get("mde_sha256"), state_path)
    diffs = config_differences(recorded, cfg)
    if mismatched:
        what = (
            f"it differs in {'; '.join(diffs)}"
            if diffs
            else "its config.json is missing or unreadable, so the differing fields cannot be listed"
        )
        raise RunDirectoryError(
            f"{out} holds results of a different configuration ({', '.join(mismatched)}): {what}. Nothing was "
            f"changed. Resume it with its own configuration (see {out / 'config.json'}), or write this run to a new "
            f"directory (hydra.run.dir=...); to discard those results, delete {out}."
        )
    if longer:
        raise RunDirectoryError(
            f"experiment.iterations = {iterations}: {out} holds more completed iterations ({', '.join(longer)}). "
            f"Nothing was changed. Allowed: at least as many iterations as it holds, or a new directory "
            f"(hydra.run.dir=...)"
        )
    if diffs and not resumable:
        log.warning(
            "%s was started with another configuration (%s) but completed no iteration: starting afresh",
            out,
            "; ".join(diffs),
        )
    return resumable


def check_checkpoint(path: Path, sha256: str | None, state_path: Path) -> None:
    """Cheap pre-compute check that the MDE checkpoint named by ``state.pt`` exists and has the bytes it had when
    the state was saved (``state.pt`` records its sha256: damage inside a tensor would otherwise load silently)."""
    fix = (
        f"it is the MDE of the last completed iteration, named by {state_path}. Restore it from a backup, or "
        f"delete {state_path} and run the same command again to redo this method from iteration 1 "
        f"({', '.join(METHOD_FILES[:5])} beside it are intact but are rewritten then: copy them elsewhere first "
        f"to keep them)"
    )
    if not path.is_file():
        raise RunFileError(f"{path} is missing; {fix}")
    if file_sha256(path) != sha256:
        raise RunFileError(f"{path} is damaged (its bytes do not match the checksum {state_path} recorded); {fix}")


def load_mde_checkpoint(mde_cls: Any, path: Path, expected: Any, X: Any, state_path: Path) -> Any:
    """Load ``path`` with ``mde_cls.load`` and check it belongs to ``state_path``'s run.

    ``expected`` is a fresh MDE of the configured kind: the checkpoint must have its
    configuration and have been fitted on the first ``n_train`` rows of the saved data ``X``.
    """
    fix = (
        f"restore it from a backup, or delete {state_path} and run the same command again to redo this method "
        f"from iteration 1 (the CSVs and dataset.pt beside it are intact but are rewritten then)"
    )
    try:
        mde = mde_cls.load(path)
    except Exception as e:  # noqa: BLE001
        raise RunFileError(f"MDE checkpoint {path} is unreadable ({describe_load_error(e)}); {fix}") from None
    exp_cfg, got_cfg = getattr(expected, "config", None), getattr(mde, "config", None)
    if exp_cfg is not None and got_cfg is not None and _as_dict(got_cfg) != _as_dict(exp_cfg):
        raise RunFileError(
            f"MDE checkpoint {path} was fitted with another MDE configuration than this run's (mde.*); {fix}"
        )
    n, train_X = getattr(mde, "n_train", None), getattr(mde, "train_X", None)
    if n is not None and train_X is not None and n > 0:
        X = torch.as_tensor(X)
        if n > len(X) or not torch.equal(torch.as_tensor(train_X).to(X.dtype), X[:n]):
            raise RunFileError(
                f"MDE checkpoint {path} was fitted on data that is not this method's saved data "
                f"({n} points, {len(X)} saved in {state_path}); {fix}"
            )
    return mde


def _as_dict(c: Any) -> Any:
    return c.to_dict() if hasattr(c, "to_dict") else c


def clean_leftovers(out: Path) -> list[Path]:
    """Remove temporary files killed writers left in the run directory and its sub-directories.

    Only while holding the directory's lock (a live writer's temporary file looks the same).
    """
    removed = safeio.remove_orphans(out)
    for sub in sorted(p for p in out.iterdir() if p.is_dir() and not p.name.startswith(".") and p.name != "wandb"):
        removed += safeio.remove_orphans(sub)
    if removed:
        log.info("removed %d temporary file(s) left by a killed run: %s", len(removed), [str(p) for p in removed])
    return removed
