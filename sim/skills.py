"""Parameterised skills as kinematic cup trajectories, with contact against static obstacles.

Actions are (skill_id, p1, p2): ``move(x, y)`` = (0, x, y) carries the upright cup along a straight
line with a min-jerk profile whose peak speed is bounded; ``pour(theta, hold)`` = (1, theta, hold)
tilts the cup counter-clockwise about its pouring lip to theta, holds, and returns upright. Every
skill ends with a settle period. The cup is kinematic and the obstacles are static, so each
environment's whole pose-versus-time schedule is computed before simulating: if the cup would enter
an obstacle (plant, target cup, tank wall), it stops at the last contact-free pose and stays there
("stuck"); the rest of that trajectory is not executed. With ``world.plant.on_contact: hold`` a cup
blocked by the plant (foliage, not a rigid structure) stays at the leaf only for the rest of that
action, and the trajectory goes on from there: the next actions, and their labels, are observed. With
``stuck`` the cup stays caught for the rest of the trajectory: the schedule ends as with ``stop``, and the
executor records each action left as attempted without effect (:meth:`sim.execute.PouringExecutor.run`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from task import on_lattice

from .engine.motion import cos_sin, min_jerk, min_jerk_duration
from .engine.scene import Body, Shape
from .world import WorldConfig

MOVE, POUR = 0, 1
SKILLS = {"move": MOVE, "pour": POUR}
CONTACT_MARGIN = 0.001  # m: closer than this to an obstacle counts as contact


def move(x: float, y: float) -> np.ndarray:
    return np.array([MOVE, x, y], float)


def pour(theta: float, hold: float) -> np.ndarray:
    return np.array([POUR, theta, hold], float)


def validate_actions(cfg: WorldConfig, seqs: Sequence[Sequence[Sequence[float]]]) -> list[np.ndarray]:
    """Check (or clip, with ``skills.clip_parameters``) every action before anything is simulated.

    Returns the actions as the world executes them: move targets on the world's ``skills.lattice``
    (as :func:`plan_schedule` moves the cup), so recorded transitions pair each outcome with the
    action that produced it, not with the one that was asked for."""
    sk = cfg.skills
    lattice = sk.get("lattice", 0.0)
    out = []
    for i, seq in enumerate(seqs):
        a = np.asarray(seq, float)
        if a.ndim != 2 or a.shape[1] != 3 or len(a) == 0:
            raise ValueError(f"action sequence {i}: expected a non-empty list of (skill, p1, p2), got shape {a.shape}")
        if len(a) > sk["max_actions"]:
            raise ValueError(f"action sequence {i}: {len(a)} actions > skills.max_actions = {sk['max_actions']}")
        a = a.copy()
        for t, (kind, p1, p2) in enumerate(a):
            if kind not in (MOVE, POUR):
                raise ValueError(f"action sequence {i} step {t}: skill id {kind:g}: allowed {SKILLS}")
            names = ("move.x", "move.y") if kind == MOVE else ("pour.theta", "pour.hold")
            for j, (name, val) in enumerate(zip(names, (p1, p2))):
                lo, hi = sk[name.split(".")[0]][name.split(".")[1]]
                if not (lo - 1e-9 <= val <= hi + 1e-9) or not math.isfinite(val):
                    if sk.get("clip_parameters") and math.isfinite(val):
                        a[t, 1 + j] = min(max(val, lo), hi)
                    else:
                        raise ValueError(
                            f"action sequence {i} step {t}: {name} = {val:g} outside its range "
                            f"[{lo:g}, {hi:g}] (skills.{name}; set skills.clip_parameters to clip)"
                        )
        moves = a[:, 0] == MOVE
        a[moves, 1:3] = on_lattice(a[moves, 1:3], lattice)
        out.append(a)
    return out


# ---------------------------------------------------------------------------------- geometry
def _sdf_shape(shape: Shape, pose: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Signed distance of world points p (n, 2) to a shape of a body at ``pose``."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    d = p - pose[:2]
    q = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1) - np.asarray(shape.center)
    ca, sa = math.cos(shape.angle), math.sin(shape.angle)
    q = np.stack([ca * q[:, 0] + sa * q[:, 1], -sa * q[:, 0] + ca * q[:, 1]], 1)
    size = np.asarray(shape.size)
    if shape.kind == "box":
        a = np.abs(q) - size
        return np.linalg.norm(np.maximum(a, 0), axis=1) + np.minimum(a.max(1), 0)
    if shape.kind == "capsule":
        cx = np.clip(q[:, 0], -size[0], size[0])
        return np.hypot(q[:, 0] - cx, q[:, 1]) - size[1]
    k0 = np.linalg.norm(q / size, axis=1)
    k1 = np.linalg.norm(q / size**2, axis=1)
    return np.where(k0 < 1, (k0 - 1) * size.min(), k0 * (k0 - 1) / np.maximum(k1, 1e-12))


@dataclass
class Obstacles:
    """Static obstacles of one environment (bodies + tank interior) as a numpy SDF."""

    bodies: list[Body]
    interior_lo: np.ndarray
    interior_hi: np.ndarray

    def sdf(self, p: np.ndarray, cutoff: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(distance, index of the closest obstacle: body index, or -1 for the tank walls).

        ``cutoff``: only distances below it need be exact (contact tests): a shape is evaluated only at
        points within ``cutoff`` of its bounding circle, so far-away shapes cost nothing. Where the
        true distance is below ``cutoff`` the result (distance and index) is the same as without it;
        elsewhere it may be an upper bound of the true distance (from the shapes that were evaluated).
        Not quite for ellipses: their distance estimate can dip below ``cutoff`` at points just outside
        the bounding circle grown by ``cutoff``, which this skips (rare grazes; :meth:`outline_sdf` does not).
        """
        walls = np.minimum((p - self.interior_lo).min(1), (self.interior_hi - p).min(1))
        best, idx = walls, np.full(len(p), -1)
        for k, pose, sh, centre in self._shapes():
            if cutoff is None:
                sel = slice(None)
            else:
                sel = np.flatnonzero(np.hypot(*(p - centre).T) - sh.bounding_radius() < cutoff)
                if not len(sel):
                    continue
            d = _sdf_shape(sh, pose, p[sel])
            closer = d < best[sel]
            best[sel] = np.where(closer, d, best[sel])
            idx[sel] = np.where(closer, k, idx[sel])
        return best, idx

    def _shapes(self):
        """(body index, body pose, shape, the shape's centre in the world) for every obstacle shape."""
        for k, body in enumerate(self.bodies):
            pose = np.asarray(body.pose, float)
            c, s = math.cos(pose[2]), math.sin(pose[2])
            for sh in body.shapes:
                cx, cy = sh.center
                yield k, pose, sh, pose[:2] + (c * cx - s * cy, s * cx + c * cy)

    def outline_sdf(self, boundary: np.ndarray, poses: np.ndarray, cutoff: float) -> tuple[np.ndarray, np.ndarray]:
        """(distance, obstacle index), each (n, m): the outline ``boundary`` (m, 2, body frame) at ``poses`` (n, 3).

        The same answer as the full ``sdf(to_world(boundary, poses, portable=True).reshape(-1, 2))`` (no
        cutoff) where that distance is below ``cutoff`` (elsewhere it may be larger, +inf included), found
        faster (and with libm's trigonometry, as the schedule needs): an obstacle (tank walls,
        each shape) is evaluated only at the poses whose outline's bounding circle comes within ``cutoff``
        of it, so a cup path far from everything costs one circle test per pose and obstacle.
        """
        n, m = len(poses), len(boundary)
        c0 = 0.5 * (boundary.min(0) + boundary.max(0))
        r = float(np.linalg.norm(boundary - c0, axis=1).max())
        centre = to_world(c0[None], poses, portable=True)[:, 0]  # (n, 2)
        pts = to_world(boundary, poses, portable=True)  # (n, m, 2)
        best, idx = np.full((n, m), np.inf), np.full((n, m), -1)
        wall = np.minimum((centre - self.interior_lo).min(1), (self.interior_hi - centre).min(1))
        rows = np.flatnonzero(wall < r + cutoff)
        if rows.size:
            p = pts[rows]
            best[rows] = np.minimum((p - self.interior_lo).min(2), (self.interior_hi - p).min(2))
        for k, pose, sh, sc in self._shapes():
            rows = np.flatnonzero(np.hypot(*(centre - sc).T) < r + sh.bounding_radius() + cutoff)
            if not rows.size:
                continue
            d = _sdf_shape(sh, pose, pts[rows].reshape(-1, 2)).reshape(rows.size, m)
            closer = d < best[rows]
            best[rows] = np.where(closer, d, best[rows])
            idx[rows] = np.where(closer, k, idx[rows])
        return best, idx


def cup_boundary(cfg: WorldConfig, spacing: float = 0.003) -> np.ndarray:
    """Points along the controlled cup's outline (body frame) for contact tests."""
    pts = []
    for sh in cfg.controlled_cup.shapes():
        poly = sh.outline()
        for a, b in zip(poly, np.roll(poly, -1, 0)):
            n = max(2, int(np.ceil(np.linalg.norm(b - a) / spacing)))
            pts.append(a + (b - a) * np.linspace(0, 1, n, endpoint=False)[:, None])
    return np.concatenate(pts)


def to_world(points: np.ndarray, poses: np.ndarray, portable: bool = False) -> np.ndarray:
    """points (m, 2) in the body frame, poses (k, 3) -> (k, m, 2) world points (``portable``: :func:`cos_sin`)."""
    c, s = cos_sin(poses[:, 2], portable)
    c, s = c[:, None], s[:, None]
    x = c * points[None, :, 0] - s * points[None, :, 1] + poses[:, None, 0]
    y = s * points[None, :, 0] + c * points[None, :, 1] + poses[:, None, 1]
    return np.stack([x, y], -1)


def tilt_about_lip(start: np.ndarray, lip: np.ndarray, phi: np.ndarray, portable: bool = False) -> np.ndarray:
    """Cup poses (n, m, 3) when cups at ``start`` (n, 3) are turned about their pouring lip (body frame
    point ``lip``) to absolute angles ``phi`` (n, m): origin = pivot - R(phi) lip, pivot fixed
    (``portable``: :func:`cos_sin`)."""
    c, s = cos_sin(start[:, 2], portable)
    px = start[:, 0] + c * lip[0] - s * lip[1]
    py = start[:, 1] + s * lip[0] + c * lip[1]
    cp, sp = cos_sin(phi, portable)
    ox = px[:, None] - (cp * lip[0] - sp * lip[1])
    oy = py[:, None] - (sp * lip[0] + cp * lip[1])
    return np.stack([ox, oy, phi], -1)


# ---------------------------------------------------------------------------------- schedules
@dataclass
class Schedule:
    """Cup poses on the control grid for one environment and the tick that ends each action."""

    poses: np.ndarray  # (K + 1, 3), pose at tick k (time k * control_dt)
    action_end: list[int] = field(default_factory=list)  # tick at which action i's settle ends
    executed: int = 0  # actions executed (the last one may be stuck)
    stuck_on: str | None = None  # name of the first blocking obstacle body ("plant", "target") or "tank"
    blocked: list[int] = field(default_factory=list)  # indices of the actions that were blocked

    @property
    def stuck(self) -> bool:
        """Some action was blocked (it ended the trajectory unless the plant held it)."""
        return bool(self.blocked)


def start_overlap(obstacles: "Obstacles", boundary: np.ndarray, pose: np.ndarray) -> str | None:
    """What the cup at ``pose`` overlaps ("tank wall" or "<name> body"), or None when it is clear.

    The one start check of both the executor and the differentiable pour (each words its error)."""
    d, idx = obstacles.sdf(to_world(boundary, np.asarray(pose, float)[None], portable=True)[0])
    if d.min() >= 0:
        return None
    who = int(idx[np.argmin(d)])
    return "tank wall" if who < 0 else f"{obstacles.bodies[who].name} body"


def plan_schedule(
    cfg: WorldConfig, start: np.ndarray, actions: np.ndarray, obstacles: Obstacles, boundary: np.ndarray
) -> Schedule:
    """Pose-versus-tick schedule of a whole action sequence, stopping at the first contact (the plant's
    contacts only block their action when ``cfg.plant_on_contact == "hold"``)."""
    h = cfg.control_dt
    sk = cfg.skills
    settle = int(round(sk["settle"] / h))
    poses = [np.asarray(start, float)]
    sched = Schedule(poses=np.zeros((1, 3)))
    lip = cfg.controlled_cup.lip
    hold_plant = cfg.plant_on_contact == "hold"
    for i, a in enumerate(actions):
        p0 = poses[-1]
        kind = int(a[0])
        if kind == MOVE:
            goal = np.array([*on_lattice(a[1:3], sk.get("lattice", 0.0)), p0[2]])
            T = float(min_jerk_duration(np.linalg.norm(goal[:2] - p0[:2]), sk["move"]["peak_speed"], min_time=h))
            n = int(np.ceil(T / h))
            seg = p0 + (goal - p0) * min_jerk(np.arange(1, n + 1) * h / T)[:, None]
        else:
            theta, hold = float(a[1]), float(a[2])
            T = float(min_jerk_duration(theta, sk["pour"]["peak_rate"], min_time=h))
            n = int(np.ceil(T / h))
            tilt = theta * min_jerk(np.arange(1, n + 1) * h / T)
            back = theta * (1 - min_jerk(np.arange(1, n + 1) * h / T))
            angles = np.concatenate([tilt, np.full(int(round(hold / h)), theta), back])
            seg = tilt_about_lip(p0[None], lip, (p0[2] + angles)[None], portable=True)[0]
        d, idx = obstacles.outline_sdf(boundary, seg, CONTACT_MARGIN)
        hit = np.flatnonzero(d.min(1) < CONTACT_MARGIN)
        sched.executed += 1
        ends = False
        if len(hit):
            k = int(hit[0])
            j = int(np.argmin(d[k]))
            who = int(idx[k, j])
            name = "tank" if who < 0 else obstacles.bodies[who].name
            sched.stuck_on = sched.stuck_on or name
            sched.blocked.append(i)
            ends = not (hold_plant and name == "plant")
            stop = seg[k - 1] if k > 0 else p0
            seg = np.concatenate([seg[:k], np.repeat(stop[None], len(seg) - k, 0)])
        poses.extend(seg)
        poses.extend([poses[-1]] * settle)
        sched.action_end.append(len(poses) - 1)
        if ends:
            break
    sched.poses = np.asarray(poses)
    return sched


def random_actions(cfg: WorldConfig, n: int, rng: np.random.Generator, p_pour: float = 0.5) -> np.ndarray:
    """``n`` uniformly random actions (skill chosen with probability ``p_pour`` of a pour)."""
    sk = cfg.skills
    out = np.empty((n, 3))
    for i in range(n):
        if rng.random() < p_pour:
            out[i] = pour(rng.uniform(*sk["pour"]["theta"]), rng.uniform(*sk["pour"]["hold"]))
        else:
            out[i] = move(rng.uniform(*sk["move"]["x"]), rng.uniform(*sk["move"]["y"]))
    return out
