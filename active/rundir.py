"""What a run may reuse from its directory, checked before any compute.

A run directory holds results only one configuration may extend: per method ``state.pt`` (with the
digest of the configuration that wrote it), ``mde_iterNNN.pt`` checkpoints, and the shared
``calibration_set.pt``. Everything reused is checked against the configuration that made it; a
mismatch is refused (results) or rebuilt (the calibration set, a deterministic function of the
configuration), never used silently; ``config.json`` is rewritten only after the directory was
accepted, so a refused rerun leaves the directory describing its own results.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path
from typing import Any, Mapping

import safeio

from .io import RunFileError, as_json, describe_load_error, load_torch, save_torch
from .runlock import RunDirectoryError

log = logging.getLogger(__name__)

CALIBRATION_FORMAT = "active-mde/calibration-set"
CALIBRATION_VERSION = 1
#: files a method directory holds besides state.pt (named in messages about what survives)
METHOD_FILES = ("results.csv", "categories.csv", "calibration.csv", "tests.csv", "dataset.pt", "mde_iter*.pt")


# ------------------------------------------------------------------ digests
def legacy_config_digest(cfg: Mapping[str, Any]) -> str:
    """The digest state.pt files got before the cache location was excluded (still accepted)."""
    c = as_json(cfg)
    for k in ("iterations", "methods"):
        c.get("experiment", {}).pop(k, None)
    for k in ("wandb", "progress", "method"):
        c.pop(k, None)
    if isinstance(c.get("acquisition"), dict):
        from .loop import legacy_acquisition

        c["acquisition"] = legacy_acquisition(c["acquisition"])
    return hashlib.sha256(json.dumps(c, sort_keys=True).encode()).hexdigest()[:16]


def accepted_digests(cfg: Mapping[str, Any], recorded: Mapping[str, Any] | None) -> frozenset[str]:
    """Digests of state written by a configuration whose results are comparable with ``cfg``.

    The current digest, the legacy one of ``cfg``, and - when the directory's ``config.json``
    (``recorded``, read in today's form: :func:`upgrade_config`) is comparable with ``cfg`` - the
    digests of the recorded configuration (a finished run whose dynamics cache has moved since, or
    one recorded before the planner's keys were derived).
    """
    from .loop import config_digest

    out = {config_digest(cfg), legacy_config_digest(cfg)}
    if recorded is not None and config_digest(upgrade_config(recorded)) == config_digest(cfg):
        out.update({config_digest(recorded), legacy_config_digest(recorded)})
    return frozenset(out)


#: experiment keys a config written before every experiment YAML set them could lack, with the value
#: the run then had (the dataclass default)
PRE_DERIVATION_EXPERIMENT = {"planner_time_budget": 30.0, "known_obstacles": True, "refine_steps": 0,
                             "refine_lr": 0.05}


def upgrade_config(cfg: Mapping[str, Any]) -> dict:
    """A configuration recorded before the planner's task and protocol keys were derived, in today's form.

    Such a ``planner:`` block held ``beta``, ``seed``, ``goal_tol``, a ``problems:`` block and literal
    values of the keys :data:`active.loop.DERIVED_PLANNER_KEYS` now interpolates, which the run
    overwrote (and widened the state bounds to the action ranges); it is rewritten with the values
    that acted, so its results count as this configuration's. Any other configuration comes back as
    a copy, with the experiment and MDE keys added since it was recorded at the values that acted then (off)."""
    from .loop import DERIVED_PLANNER_KEYS, NEUTRAL_EXPERIMENT_SETTINGS, NEUTRAL_MDE_SETTINGS

    c = as_json(cfg)
    for group, neutral in (("experiment", NEUTRAL_EXPERIMENT_SETTINGS), ("mde", NEUTRAL_MDE_SETTINGS)):
        if isinstance(c.get(group), dict):  # a key added later acted at its off value before it existed, whatever
            for k, off in neutral.items():  # today's default (the MDE's priors: session 41; the aim: session 42)
                c[group].setdefault(k, off)
    p, w, e = c.get("planner"), c.get("world"), c.get("experiment")
    if not (isinstance(p, dict) and isinstance(p.get("problems"), dict) and isinstance(w, dict)
            and isinstance(e, dict)):
        return c
    for k, v in PRE_DERIVATION_EXPERIMENT.items():
        e.setdefault(k, v)
    for k in ("beta", "seed", "goal_tol", "problems"):
        p.pop(k, None)
    try:
        for k, src in DERIVED_PLANNER_KEYS.items():
            cur: Any = c
            for part in src.split("."):
                cur = cur[part]
            p[k] = cur
        lo, hi = list(p["state_low"]), list(p["state_high"])
        lo[0], hi[0] = min(lo[0], p["move_x"][0]), max(hi[0], p["move_x"][1])
        lo[1], hi[1] = min(lo[1], p["move_y"][0]), max(hi[1], p["move_y"][1])
        hi[2] = max(hi[2], p["pour_theta"][1])
    except (KeyError, TypeError, IndexError):  # not a complete configuration: nothing to match
        return as_json(cfg)
    p["state_low"], p["state_high"] = lo, hi
    return c


def config_differences(old: Mapping[str, Any] | None, new: Mapping[str, Any], limit: int = 12) -> list[str]:
    """``key: old -> new`` for the result-relevant fields that differ (dotted keys)."""
    from .loop import comparable_config

    if old is None:
        return []
    a, b = _flat(comparable_config(upgrade_config(old))), _flat(comparable_config(new))
    diffs = [f"{k}: {a.get(k, '(absent)')!r} -> {b.get(k, '(absent)')!r}" for k in sorted(set(a) | set(b))
             if a.get(k, "(absent)") != b.get(k, "(absent)")]
    return diffs[:limit] + ([f"... and {len(diffs) - limit} more"] if len(diffs) > limit else [])


def _flat(d: Any, prefix: str = "") -> dict[str, Any]:
    if not isinstance(d, dict):
        return {prefix: d}
    out: dict[str, Any] = {}
    for k, v in d.items():
        out.update(_flat(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


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
        log.warning("%s is unreadable (%s); the state files decide whether this directory can be resumed, and "
                    "it is rewritten once they have been checked", path, e)
        return None


def state_fix(path: Path) -> str:
    """What to do about an unusable ``<method>/state.pt``, and what survives it."""
    kept = sorted({p.name for pat in METHOD_FILES for p in path.parent.glob(pat)})
    kept_txt = f"{', '.join(kept)} beside it are intact and kept" if kept else "nothing else of this method was saved"
    return (f"{kept_txt}, as are the other methods of {path.parent.parent} and its calibration set, but this method "
            f"cannot resume without state.pt. Restore it from a backup, or delete it and run the same command again "
            f"to redo this method from iteration 1 (its CSVs, dataset.pt and checkpoints are then rewritten: copy "
            f"them elsewhere first to keep them)")


def check_run_directory(out: Path, cfg: Mapping[str, Any]) -> tuple[frozenset[str], bool]:
    """Refuse, before any compute, a directory holding results of another configuration.

    Reads every ``*/state.pt`` (errors name the file and what survives) and checks its digest
    and that its MDE checkpoint is readable. Returns the state digests that may be resumed and
    whether any method has resumable state. Leftovers of a run of another configuration that
    never completed an iteration are not results: such a directory is accepted (the calibration
    set is checked on its own).
    """
    recorded = read_recorded_config(out)
    accepted = accepted_digests(cfg, recorded)
    mismatched, resumable = [], False
    for state_path in sorted(out.glob("*/state.pt")):
        st = load_torch(state_path, fix=state_fix(state_path))
        if not isinstance(st, dict) or "digest" not in st or "completed" not in st:
            raise RunFileError(f"{state_path} is not a state file of this runner; {state_fix(state_path)}")
        if st["digest"] not in accepted:
            mismatched.append(f"{state_path.parent.name} ({st['completed']} iterations)")
            continue
        resumable = True
        if st.get("mde_path"):
            _check_readable_checkpoint(state_path.parent / st["mde_path"], state_path)
    if mismatched:
        diffs = config_differences(recorded, cfg)
        what = (f"it differs in {'; '.join(diffs)}" if diffs else
                "its config.json is missing or unreadable, so the differing fields cannot be listed")
        raise RunDirectoryError(
            f"{out} holds results of a different configuration ({', '.join(mismatched)}): {what}. Nothing was "
            f"changed. Resume it with its own configuration (see {out / 'config.json'}), or write this run to a new "
            f"directory (hydra.run.dir=...); to discard those results, delete {out}.")
    diffs = config_differences(recorded, cfg)
    if diffs and not resumable:
        log.warning("%s was started with another configuration (%s) but completed no iteration: starting afresh",
                    out, "; ".join(diffs))
    return accepted, resumable


def _check_readable_checkpoint(path: Path, state_path: Path) -> None:
    """Cheap pre-compute check that a checkpoint named by state.pt exists and unpickles."""
    import torch

    fix = (f"it is the MDE of the last completed iteration, named by {state_path}. Restore it from a backup, or "
           f"delete {state_path} and run the same command again to redo this method from iteration 1 "
           f"({', '.join(METHOD_FILES[:5])} beside it are intact but are rewritten then: copy them elsewhere first "
           f"to keep them)")
    if not path.is_file():
        raise RunFileError(f"{path} is missing; {fix}")
    try:
        torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001
        raise RunFileError(f"{path} is unreadable ({describe_load_error(e)}); {fix}") from None


def load_mde_checkpoint(mde_cls: Any, path: Path, expected: Any, X: Any, state_path: Path) -> Any:
    """Load ``path`` with ``mde_cls.load`` and check it belongs to ``state_path``'s run.

    ``expected`` is a fresh MDE of the configured kind: the checkpoint must have its
    configuration and have been fitted on the first ``n_train`` rows of the saved data ``X``.
    """
    import torch

    fix = (f"restore it from a backup, or delete {state_path} and run the same command again to redo this method "
           f"from iteration 1 (the CSVs and dataset.pt beside it are intact but are rewritten then)")
    try:
        mde = mde_cls.load(path)
    except Exception as e:  # noqa: BLE001
        raise RunFileError(f"MDE checkpoint {path} is unreadable ({describe_load_error(e)}); {fix}") from None
    exp_cfg, got_cfg = getattr(expected, "config", None), getattr(mde, "config", None)
    if exp_cfg is not None and got_cfg is not None and _as_dict(got_cfg) != _as_dict(exp_cfg):
        raise RunFileError(f"MDE checkpoint {path} was fitted with another MDE configuration than this run's "
                           f"(mde.*); {fix}")
    n, train_X = getattr(mde, "n_train", None), getattr(mde, "train_X", None)
    if n is not None and train_X is not None and n > 0:
        X = torch.as_tensor(X)
        if n > len(X) or not torch.equal(torch.as_tensor(train_X).to(X.dtype), X[:n]):
            raise RunFileError(f"MDE checkpoint {path} was fitted on data that is not this method's saved data "
                               f"({n} points, {len(X)} saved in {state_path}); {fix}")
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


# ------------------------------------------------------------------ the calibration set
def load_calibration(path: Path, cfg: Mapping[str, Any], accepted: frozenset[str],
                     trust_untagged: bool) -> dict | None:
    """The directory's held-out calibration set if ``cfg`` made it, else None (it must be rebuilt).

    Read before any compute. The file records the digest of the configuration that made it;
    another one (e.g. a run of another seed killed before its first iteration) is not reused
    (warned). A file from before the digest was recorded is reused only if ``trust_untagged``
    (a resumable state of this configuration vouches for it), and is then tagged. A damaged
    file is an error naming it and the fix.
    """
    if not path.exists():
        return None
    fix = (f"delete it and run the same command again: it is rebuilt from the configuration (the same set for the "
           f"same configuration); results, checkpoints and datasets in {path.parent} are kept")
    data = load_torch(path, fix=fix)
    if isinstance(data, dict) and data.get("format") == CALIBRATION_FORMAT:
        if data.get("digest") in accepted:
            return {"X": data["X"], "y": data["y"]}
        diffs = config_differences(data.get("config"), cfg)
        log.warning("%s was made by another configuration (%s); rebuilding it", path,
                    "; ".join(diffs) or f"digest {data.get('digest')}")
        return None
    if isinstance(data, dict) and "X" in data and "y" in data:
        if trust_untagged:
            save_calibration(path, data, cfg)
            return {"X": data["X"], "y": data["y"]}
        log.warning("%s does not record which configuration made it and no completed iteration in this directory "
                    "vouches for it (a run killed before its first iteration?); rebuilding it", path)
        return None
    raise RunFileError(f"{path} is not a calibration set (a dict with X and y); {fix}")


def save_calibration(path: Path, cal: Mapping[str, Any], cfg: Mapping[str, Any]) -> dict:
    """Write the calibration set tagged with the configuration that made it; returns its X and y."""
    from .loop import config_digest

    save_torch(path, {"format": CALIBRATION_FORMAT, "version": CALIBRATION_VERSION, "digest": config_digest(cfg),
                      "config": as_json(cfg), "X": cal["X"], "y": cal["y"]})
    return {"X": cal["X"], "y": cal["y"]}
