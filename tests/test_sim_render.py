"""Window-less rendering: PNG of one environment and a GIF of a rollout."""

import numpy as np
from PIL import Image

from benchmarks.validate import CupGeometry, cup_scene
from sim.engine.render import save_gif, save_png, snapshot

#: tests/test_sim_solver.py's configuration (``shared_solver``: one compile when both files run in one process)
BASE = dict(domain=(0.6, 0.6), dt=4e-4, n_envs=3, max_particles=512)


def test_png_and_gif_show_water_and_colliders(tmp_path, shared_solver):
    solver = shared_solver(**BASE)
    cups = [cup_scene(CupGeometry(), (0.3, 0.1, 0.0)), cup_scene(CupGeometry(), (0.2, 0.1, 0.2))]
    solver.reset(cups + cups[:1])
    png = save_png(solver, tmp_path / "frame.png", env=1)
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    grey = (np.abs(img - np.array([0x8C, 0x8C, 0x8C])).sum(-1) < 20).sum()
    blue = ((img[..., 2] - img[..., 0]) > 60).sum()
    assert grey > 100 and blue > 100  # container and water both visible, in distinct colours

    snaps = []
    for _ in range(3):
        solver.advance(0.02)
        snaps.append(snapshot(solver, 0))
    gif = save_gif(snaps, solver.specs[0], solver.cfg.domain, solver.cfg.wall, tmp_path / "roll.gif")
    with Image.open(gif) as im:
        assert im.n_frames == 3
