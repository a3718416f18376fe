"""Where does a skill's cup path first touch the known static geometry? A vectorised, approximate
version of the contact test that :func:`sim.skills.plan_schedule` runs tick by tick.

Why: the learned dynamics model is trained on source-world data and rarely sees the cup stopped by
the target cup or the tank walls, yet those are fixed and known in both worlds. A planner that
knows where they are need not learn them from target-world failures (the plant, which it does not
know, stays the model deviation the MDE has to learn). Batched over many (pose, action) pairs,
with a cheap bounding-circle filter first, so that the planner can call it on every propagation.

The path of each action is sampled at ``samples`` points (then refined inside the first touching
interval); the cup's closed outer box is sampled every ``spacing`` metres and the obstacles'
outline vertices are tested against that box. A path that passes within ``clearance`` of an
obstacle counts as stuck (conservative: the samples can step over a grazing contact). Agreement with the simulator's
schedule is checked in ``tests/test_sim_contact.py``.

The obstacles' distance is read from a raster (:class:`DistanceRaster`, bilinear, ``resolution`` metres)
rather than evaluated shape by shape: a planner calls this with ~17 rows at a time, where the cost is the
number of numpy calls, not their size (evaluated shape by shape, the contact check took 42 % of a planner's
time: BENCHMARKS.md, planner throughput).
"""

from __future__ import annotations

import numpy as np

from task import on_lattice

from .skills import CONTACT_MARGIN, MOVE, Obstacles, cup_boundary, to_world
from .world import WorldConfig, check_world


class DistanceRaster:
    """The obstacle bodies' signed distance (tank walls aside) sampled on a grid, read bilinearly.

    Why: one bilinear read is a dozen numpy calls whatever the number of shapes, where
    :meth:`Obstacles.sdf` makes a dozen per shape. The grid covers the bodies' bounding box grown by
    ``reach``; farther points get the walls' distance only (only distances below ``reach`` are wanted).
    Error: none where the distance is linear across a cell (along a face), up to about a quarter of
    ``resolution`` next to a corner (0.25 mm measured at 1 mm, tests/test_sim_contact.py); the closest
    body is the one at the nearest grid node.
    """

    def __init__(self, obstacles: Obstacles, resolution: float, reach: float):
        if not resolution > 0:
            raise ValueError(f"resolution = {resolution}: allowed a grid spacing > 0 (m)")
        self.h = float(resolution)
        self.walls = Obstacles([], obstacles.interior_lo, obstacles.interior_hi)
        pts = [to_world(sh.outline(), np.asarray(b.pose, float)[None])[0] for b in obstacles.bodies for sh in b.shapes]
        if not pts:
            self.lo, self.shape = np.zeros(2), (0, 0)
            return
        allp = np.concatenate(pts)
        self.lo = allp.min(0) - reach - 2 * self.h
        self.shape = tuple(int(n) for n in np.ceil((allp.max(0) + reach + 2 * self.h - self.lo) / self.h) + 1)
        gx, gy = np.meshgrid(*(self.lo[i] + self.h * np.arange(self.shape[i]) for i in range(2)), indexing="ij")
        nodes = np.stack([gx.ravel(), gy.ravel()], 1)
        bodies_only = Obstacles(obstacles.bodies, np.full(2, -np.inf), np.full(2, np.inf))
        d, idx = bodies_only.sdf(nodes)
        self.d, self.idx = d.reshape(self.shape), idx.reshape(self.shape)
        self.flat = self.d.ravel()  # read by linear index (ContactPredictor's touch test)

    def __call__(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance, closest obstacle: body index or -1 for the tank walls) of points p (k, 2)."""
        best, idx = self.walls.sdf(p)
        if not self.shape[0]:
            return best, idx
        f = (p - self.lo) / self.h
        i = np.floor(f).astype(int)
        inside = ((i >= 0) & (i < np.array(self.shape) - 1)).all(1)
        k = np.flatnonzero(inside)
        if k.size:
            ix, iy = i[k, 0], i[k, 1]
            tx, ty = (f[k] - i[k]).T
            g = self.d
            d = (1 - tx) * ((1 - ty) * g[ix, iy] + ty * g[ix, iy + 1]) + tx * (
                (1 - ty) * g[ix + 1, iy] + ty * g[ix + 1, iy + 1]
            )
            near = np.rint(f[k]).astype(int)
            closer = d < best[k]
            best[k] = np.where(closer, d, best[k])
            idx[k] = np.where(closer, self.idx[near[:, 0], near[:, 1]], idx[k])
        return best, idx


class ContactPredictor:
    """First contact of move / pour paths with one world's static obstacles (no plant jitter)."""

    def __init__(
        self,
        cfg: WorldConfig,
        world: str = "source",
        samples: int = 24,
        refine: int = 8,
        spacing: float = 0.06,
        clearance: float = 0.002,
        resolution: float | None = 0.001,
    ):
        """``resolution``: grid spacing (m) of the obstacles' distance raster; None evaluates every shape
        exactly at every point (slower; the reference of the raster's test)."""
        check_world(world)
        if samples < 2 or refine < 1:
            raise ValueError(f"samples = {samples}, refine = {refine}: allowed samples >= 2 and refine >= 1")
        if clearance < 0:
            raise ValueError(f"clearance = {clearance}: allowed a distance >= 0 (m)")
        if resolution is not None and not resolution > 0:
            raise ValueError(f"resolution = {resolution}: allowed a grid spacing > 0 (m) or None (exact distances)")
        self.cfg, self.samples, self.refine = cfg, int(samples), int(refine)
        #: a path closer than this to an obstacle counts as stuck: the simulator's contact margin
        #: plus a safety clearance that covers the path sampling (grazing paths count as stuck)
        self.margin = CONTACT_MARGIN + float(clearance)
        spec = cfg.scene(world, (0.3, 0.2, 0.0))
        lo = np.full(2, cfg.floor)
        hi = np.asarray(cfg.sim["domain"], float) - cfg.floor
        self.obstacles = Obstacles(spec.bodies[1:], lo, hi)
        # the outer outline with the mouth closed: an obstacle can only reach the inside of the
        # cup through its mouth, crossing the mouth line first
        w = cfg.controlled_cup.inner_width / 2 + cfg.controlled_cup.wall
        h = cfg.controlled_cup.inner_height
        fl = float(cup_boundary(cfg, spacing)[:, 1].min())
        corners = np.array([[-w, fl], [w, fl], [w, h], [-w, h]])
        pts = []
        for p, q in zip(corners, np.roll(corners, -1, 0)):
            k = max(2, int(np.ceil(np.linalg.norm(q - p) / spacing)))
            pts.append(p + (q - p) * np.linspace(0, 1, k, endpoint=False)[:, None])
        self.boundary = np.concatenate(pts)
        self.centre = np.array([0.0, 0.5 * (fl + h)])
        self.half = np.array([w, 0.5 * (h - fl)])
        self.cup_radius = float(np.linalg.norm(self.boundary - self.centre, axis=1).max())
        circles, corners_w, owner = [], [], []
        for k, body in enumerate(self.obstacles.bodies):
            pts = np.concatenate([to_world(sh.outline(), np.asarray(body.pose, float)[None])[0] for sh in body.shapes])
            c = 0.5 * (pts.min(0) + pts.max(0))
            circles.append((c, float(np.linalg.norm(pts - c, axis=1).max())))
            corners_w.append(pts)
            owner.append(np.full(len(pts), k))
        self._circles = circles
        # obstacle outline vertices: a sharp obstacle corner can touch a flat cup side between the
        # cup's outline samples, so they are tested against the cup's box as well
        self._obstacle_pts = np.concatenate(corners_w) if corners_w else np.zeros((0, 2))
        self._obstacle_owner = np.concatenate(owner) if owner else np.zeros(0, int)
        self.lip = cfg.controlled_cup.lip
        self.lattice = float(cfg.skills.get("lattice", 0.0))  # where a move really ends (plan_schedule)
        self._raster = DistanceRaster(self.obstacles, resolution, 2 * self.margin) if resolution is not None else None
        self._bx, self._by = self.boundary[:, 0], self.boundary[:, 1]
        self._u = np.linspace(0.0, 1.0, self.samples + 1)[1:]  # path fractions tested, then refined
        self._sub = np.linspace(0.0, 1.0, self.refine + 1)

    # ------------------------------------------------------------------ paths
    def _path(self, p0: np.ndarray, a: np.ndarray, move: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, ...]:
        """Cup poses (x, y, theta, each (n, m)) at path fractions u (n, m) of each action: a straight move to
        its lattice target, or a tilt about the lip.

        Both formulas run on every row and ``np.where`` picks one: on the planner's batches (~16 rows) the
        number of numpy calls, not their size, is the cost."""
        x0, y0, t0 = p0[:, 0, None], p0[:, 1, None], p0[:, 2, None]
        goal = on_lattice(a[:, 1:3], self.lattice)
        lx, ly = self.lip
        c, s = np.cos(p0[:, 2]), np.sin(p0[:, 2])
        px = (p0[:, 0] + c * lx - s * ly)[:, None]
        py = (p0[:, 1] + s * lx + c * ly)[:, None]
        phi = t0 + a[:, 1, None] * u
        cp, sp = np.cos(phi), np.sin(phi)
        m = move[:, None]
        x = np.where(m, x0 + (goal[:, 0, None] - x0) * u, px - (cp * lx - sp * ly))
        y = np.where(m, y0 + (goal[:, 1, None] - y0) * u, py - (sp * lx + cp * ly))
        return x, y, np.where(m, t0 + (t0 - t0) * u, phi)

    def _touching(self, x: np.ndarray, y: np.ndarray, th: np.ndarray) -> np.ndarray:
        """Whether the cup at each pose (flat arrays) comes within the margin of an obstacle (same poses'
        outcome as ``_clearance(...)[0] < margin``, without the obstacle index)."""
        c, s = np.cos(th), np.sin(th)
        out = np.zeros(len(x), bool)
        k = np.flatnonzero(self._near_cs(x, y, c, s))
        if not k.size:
            return out
        x, y, c, s = x[k, None], y[k, None], c[k, None], s[k, None]
        bx, by = self._bx, self._by
        px = (c * bx - s * by + x).ravel()
        py = (s * bx + c * by + y).ravel()
        hit = self._outline_touching(px, py).reshape(k.size, -1).any(1)
        if len(self._obstacle_pts):
            hit |= (self._cup_sdf_cs(x, y, c, s, self._obstacle_pts) < self.margin).any(1)
        out[k] = hit
        return out

    def _outline_touching(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Whether world points (flat x, y) lie within the margin of an obstacle (``DistanceRaster``'s distance,
        or the exact one without a raster)."""
        m, r = self.margin, self._raster
        if r is None:
            return self.obstacles.sdf(np.stack([px, py], 1), cutoff=m)[0] < m
        lo, hi = r.walls.interior_lo, r.walls.interior_hi
        touch = (px - lo[0] < m) | (py - lo[1] < m) | (hi[0] - px < m) | (hi[1] - py < m)
        if not r.shape[0]:
            return touch
        fx, fy = (px - r.lo[0]) / r.h, (py - r.lo[1]) / r.h
        ix, iy = np.floor(fx).astype(int), np.floor(fy).astype(int)
        k = np.flatnonzero((ix >= 0) & (ix < r.shape[0] - 1) & (iy >= 0) & (iy < r.shape[1] - 1))
        if k.size:
            ix, iy = ix[k], iy[k]
            tx, ty = fx[k] - ix, fy[k] - iy
            g, at = r.flat, ix * r.shape[1] + iy
            d = (1 - tx) * ((1 - ty) * g[at] + ty * g[at + 1]) + tx * (
                (1 - ty) * g[at + r.shape[1]] + ty * g[at + r.shape[1] + 1]
            )
            touch[k] |= d < m
        return touch

    def _clearance(self, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Smallest obstacle distance of the cup outline (n, m) and the obstacle index (-1 = tank).

        Poses whose bounding circle is clear of every obstacle's get +inf without the outline test.
        """
        n, m = poses.shape[:2]
        flat = poses.reshape(-1, 3)
        d_out = np.full(n * m, np.inf)
        i_out = np.full(n * m, -2)
        c, s = np.cos(flat[:, 2]), np.sin(flat[:, 2])
        near = np.flatnonzero(self._near_cs(flat[:, 0], flat[:, 1], c, s))
        if near.size:
            pts = to_world(self.boundary, flat[near]).reshape(-1, 2)
            # callers only compare with the margin: the exact path need only be exact below it
            d, idx = self._raster(pts) if self._raster is not None else self.obstacles.sdf(pts, cutoff=self.margin)
            d, idx = d.reshape(near.size, -1), idx.reshape(near.size, -1)
            if len(self._obstacle_pts):
                x, y, cn, sn = flat[near, 0, None], flat[near, 1, None], c[near, None], s[near, None]
                d = np.concatenate([d, self._cup_sdf_cs(x, y, cn, sn, self._obstacle_pts)], 1)
                owners = np.broadcast_to(self._obstacle_owner, (near.size, len(self._obstacle_owner)))
                idx = np.concatenate([idx, owners], 1)
            j = d.argmin(1)
            rows = np.arange(near.size)
            d_out[near], i_out[near] = d[rows, j], idx[rows, j]
        return d_out.reshape(n, m), i_out.reshape(n, m)

    def _cup_sdf_cs(self, x: np.ndarray, y: np.ndarray, c: np.ndarray, s: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """Signed distance (k, p) of world points to the cup's closed outer box at poses (x, y and the tilt's
        cos, sin; each (k, 1))."""
        dx = pts[None, :, 0] - x
        dy = pts[None, :, 1] - y
        qx = np.abs(c * dx + s * dy - self.centre[0]) - self.half[0]
        qy = np.abs(-s * dx + c * dy - self.centre[1]) - self.half[1]
        return np.hypot(np.maximum(qx, 0), np.maximum(qy, 0)) + np.minimum(np.maximum(qx, qy), 0)

    def _near_cs(self, x: np.ndarray, y: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
        """(k,) whether a pose (x, y and the tilt's cos, sin) comes close enough to an obstacle to need the
        outline test."""
        cx = x + -s * self.centre[1]
        cy = y + c * self.centre[1]
        r = self.cup_radius + self.margin
        lo, hi = self.obstacles.interior_lo, self.obstacles.interior_hi
        near = (cx - lo[0] < r) | (cy - lo[1] < r) | (hi[0] - cx < r) | (hi[1] - cy < r)
        for cen, rad in self._circles:
            dx, dy = cx - cen[0], cy - cen[1]
            near |= np.sqrt(dx * dx + dy * dy) < r + rad
        return near

    # ------------------------------------------------------------------ public
    def first_contact(self, poses: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For cup poses (n, 3) and actions (n, 3): (stuck (n,), stop pose (n, 3), obstacle index (n,)).

        The stop pose is the last sampled pose before the first contact (the pose itself when not
        stuck: the move's target or, for a pour, the start pose, since the cup returns upright).
        Obstacle index: position in ``self.obstacles.bodies``, -1 for the tank walls, -2 for none.
        """
        p0 = np.asarray(poses, float).reshape(-1, 3)
        a = np.asarray(actions, float).reshape(-1, 3)
        n = len(p0)
        stuck = np.zeros(n, bool)
        who = np.full(n, -2)
        stop = p0.copy()
        move = np.rint(a[:, 0]) == MOVE
        stop[move, :2] = on_lattice(a[move, 1:3], self.lattice)
        if n == 0:
            return stuck, stop, who
        u = np.broadcast_to(self._u, (n, self.samples))
        touch = self._touching(*(v.ravel() for v in self._path(p0, a, move, u))).reshape(n, -1)
        rows = np.flatnonzero(touch.any(1))
        if rows.size == 0:
            return stuck, stop, who
        k = touch[rows].argmax(1)  # first touching sample
        u_lo = np.where(k > 0, u[rows, np.maximum(k - 1, 0)], 0.0)
        u_hi = u[rows, k]
        # refine inside (u_lo, u_hi]: the first touching sub-sample, and the pose before it (column 0 is u_lo)
        uu = u_lo[:, None] + (u_hi - u_lo)[:, None] * self._sub[None, :]
        x, y, th = self._path(p0[rows], a[rows], move[rows], uu)
        d, idx = self._clearance(np.stack([x, y, th], -1))
        j = (d[:, 1:] < self.margin).argmax(1)  # exists: u_hi touches
        at = np.arange(rows.size)
        stop[rows] = np.stack([x[at, j], y[at, j], th[at, j]], -1)
        stuck[rows] = True
        who[rows] = idx[at, j + 1]
        return stuck, stop, who

    def name(self, index: int) -> str:
        """Name of an obstacle index returned by :meth:`first_contact`."""
        if index == -2:
            return ""
        return "tank" if index == -1 else self.obstacles.bodies[index].name
