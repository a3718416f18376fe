"""Window-less rendering of one environment: a PNG frame or a GIF of a rollout.

Water is drawn as blue particles (dark when slow, lighter when fast), colliders as grey (containers) or green
(plant) filled outlines, the tank walls as a dark frame.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np
from matplotlib.patches import Polygon, Rectangle  # noqa: E402

import safeio

from .scene import EnvSpec  # noqa: E402

BODY_COLOURS = {"plant": "#3a8a3a"}


def snapshot(solver, env: int = 0) -> dict:
    """Everything needed to draw one environment later (cheap to keep per frame)."""
    return {
        "x": solver.positions(env).copy(),
        "v": solver.velocities(env).copy(),
        "poses": solver.all_body_poses()[env],
        "time": solver.time,
    }


def draw_frame(ax, snap: dict, spec: EnvSpec, domain: Sequence[float], wall: float, title: str = "") -> None:
    ax.clear()
    ax.add_patch(Rectangle((0, 0), domain[0], domain[1], color="#333333"))
    ax.add_patch(Rectangle((wall, wall), domain[0] - 2 * wall, domain[1] - 2 * wall, color="white"))
    for k, body in enumerate(spec.bodies):
        colour = BODY_COLOURS.get(body.name, "#8c8c8c")
        for outline in body.world_outlines(tuple(snap["poses"][k])):
            ax.add_patch(Polygon(outline, closed=True, color=colour, alpha=0.9, lw=0))
    x = snap["x"]
    if len(x):
        speed = np.linalg.norm(snap["v"], axis=1)
        ax.scatter(x[:, 0], x[:, 1], s=6, c=speed, cmap="Blues_r", vmin=0.0, vmax=4.0, linewidths=0)
    ax.set_xlim(0, domain[0])
    ax.set_ylim(0, domain[1])
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(title or f"t = {snap['time']:.2f} s", fontsize=9)


def save_png(solver, path: str | Path, env: int = 0, title: str = "") -> Path:
    """Render environment ``env`` of a solver now to a PNG file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cfg = solver.cfg
    fig, ax = plt.subplots(figsize=(5, 5 * cfg.domain[1] / cfg.domain[0]), dpi=110)
    draw_frame(ax, snapshot(solver, env), solver.specs[env], cfg.domain, cfg.wall, title)
    fig.tight_layout()
    safeio.save_figure(fig, path)
    plt.close(fig)
    return path


def save_gif(
    snaps: Sequence[dict],
    spec: EnvSpec,
    domain: Sequence[float],
    wall: float,
    path: str | Path,
    fps: int = 20,
    titles: Sequence[str] | None = None,
) -> Path:
    """Write snapshots (from :func:`snapshot`) of one environment as an animated GIF."""
    import imageio.v2 as imageio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(5, 5 * domain[1] / domain[0]), dpi=80)
    frames = []
    for i, snap in enumerate(snaps):
        draw_frame(ax, snap, spec, domain, wall, titles[i] if titles else "")
        fig.canvas.draw()
        frames.append(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy())
    plt.close(fig)
    safeio.atomic_write(path, lambda f: imageio.mimsave(f, frames, format="GIF", duration=1.0 / fps, loop=0))
    return path
