"""Weights & Biases logging that never needs the network and never stops a run.

``mode`` is ``offline`` by default (runs sync later with ``wandb sync``), ``online`` to stream, and
``disabled`` for tests. Any W&B failure is logged once as a warning and logging turns itself off.
Each (method, seed) is its own W&B run, grouped by experiment and method, whose id is derived from the run's
config digest: a killed run started again resumes the same W&B run (``resume="allow"``), so its curve
continues instead of starting a second, partial one. The lockstep runner keeps several open at once
(``reinit="create_new"``, wandb >= 0.19.10).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any, Mapping

log = logging.getLogger(__name__)
MODES = ("offline", "online", "disabled")


class Tracker:
    def __init__(
        self,
        mode: str,
        project: str,
        run_name: str,
        config: Mapping[str, Any],
        out_dir: Path,
        entity: str | None = None,
        group: str | None = None,
        run_id: str | None = None,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"wandb.mode = {mode!r}: allowed one of {MODES}")
        self.run = None
        if mode == "disabled":
            return
        try:
            import wandb

            os.environ.setdefault("WANDB_SILENT", "true")
            self._wandb = wandb
            self.run = wandb.init(
                mode=mode,
                project=project,
                entity=entity,
                group=group,
                name=run_name,
                id=run_id,
                resume="allow" if run_id else None,
                config=dict(config),
                dir=str(out_dir),
                reinit="create_new",
                settings=wandb.Settings(console="off", x_disable_stats=True),
            )
        except Exception as e:  # a broken W&B must not stop the experiment
            log.warning("W&B disabled for this run: %s", e)
            self.run = None

    def log(self, metrics: Mapping[str, Any], step: int | None = None) -> None:
        self._safe(lambda: self.run.log(dict(metrics), step=step))

    def log_images(self, images: Mapping[str, Path], step: int | None = None) -> None:
        self._safe(
            lambda: self.run.log(
                {k: self._wandb.Image(str(p)) for k, p in images.items() if Path(p).exists()}, step=step
            )
        )

    def finish(self) -> None:
        self._safe(lambda: self.run.finish())
        self.run = None

    def _safe(self, fn) -> None:
        if self.run is None:
            return
        try:
            fn()
        except Exception as e:
            log.warning("W&B logging failed, turning it off for this run: %s", e)
            self.run = None
