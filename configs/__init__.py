"""The Hydra configs of active-mde, shipped as package data.

Every consumer locates them through this package (``configs.path(...)``), never relative to its own
source file, so that a regular ``pip install .`` or a wheel finds them as an editable install does.
Holds no code of the project: any package may import it (it imports nothing of ours).
"""

from __future__ import annotations

from pathlib import Path

#: the folder of ``config.yaml`` and the config groups (world/, dynamics/, mde/, planner/, ...)
CONFIG_DIR: Path = Path(__file__).resolve().parent


def path(*parts: str) -> Path:
    """A file or group folder of the shipped configs, e.g. ``path("world", "default.yaml")``.

    Raises ``FileNotFoundError`` naming what exists when ``parts`` name nothing (a broken install)."""
    p = CONFIG_DIR.joinpath(*parts)
    if not p.exists():
        raise FileNotFoundError(
            f"no config {'/'.join(parts)} under {CONFIG_DIR} "
            f"(has: {sorted(q.name for q in CONFIG_DIR.iterdir() if not q.name.startswith('_'))})"
        )
    return p
