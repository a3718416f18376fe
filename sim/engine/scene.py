"""Plain-Python scene description: kinematic rigid bodies made of signed-distance primitives, and
water blocks. The solver copies a list of these (one per environment) into its batched fields.

Frames: every shape is given in its body's frame; a body has a world pose (x, y, theta), with theta
counter-clockwise in radians. An open-top container's body frame has its origin at the centre of the
inner floor surface, x along the floor and y up to the rim, so "inside the cup" is the box
[-w/2, w/2] x [0, h] in that frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

SHAPE_KINDS = {"box": 0, "capsule": 1, "ellipse": 2}


@dataclass
class Shape:
    """A signed-distance primitive in its body's frame.

    box: ``size`` = half extents (hx, hy); capsule: ``size`` = (half length along local x, radius);
    ellipse: ``size`` = radii (rx, ry).
    """

    kind: str
    center: tuple[float, float] = (0.0, 0.0)
    angle: float = 0.0
    size: tuple[float, float] = (0.01, 0.01)

    def __post_init__(self) -> None:
        if self.kind not in SHAPE_KINDS:
            raise ValueError(f"Shape.kind = {self.kind!r}: allowed {sorted(SHAPE_KINDS)}")
        if not all(s > 0 for s in self.size):
            raise ValueError(f"Shape.size = {self.size}: all entries must be > 0 m")

    def bounding_radius(self) -> float:
        """Radius of a circle about the shape's centre that contains the shape (exact, no margin)."""
        a, b = self.size
        return float(math.hypot(a, b) if self.kind == "box" else (a + b if self.kind == "capsule" else max(a, b)))

    def body_bounds(self, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (lo, hi) of the shape in its body's frame, widened by ``margin`` (m).

        Why: a collider query can skip every shape whose bounds do not hold the point, with four
        comparisons instead of a square root; exact for each kind (no polygon approximation), so no
        point of the shape is ever outside them."""
        a, b = self.size
        c, s = abs(math.cos(self.angle)), abs(math.sin(self.angle))
        if self.kind == "box":
            half = (c * a + s * b, s * a + c * b)
        elif self.kind == "capsule":  # a segment of half length a along local x, swept by radius b
            half = (c * a + b, s * a + b)
        else:  # ellipse with radii (a, b): the support function along the body axes
            half = (math.hypot(a * c, b * s), math.hypot(a * s, b * c))
        centre = np.asarray(self.center, float)
        half = np.asarray(half) + margin
        return centre - half, centre + half

    def outline(self, n: int = 24) -> np.ndarray:
        """Closed polygon of the shape boundary in the body frame (for drawing and bounds)."""
        if self.kind == "box":
            hx, hy = self.size
            pts = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        elif self.kind == "ellipse":
            t = np.linspace(0, 2 * np.pi, n, endpoint=False)
            pts = np.stack([self.size[0] * np.cos(t), self.size[1] * np.sin(t)], 1)
        else:
            h, r = self.size
            t1 = np.linspace(-np.pi / 2, np.pi / 2, n // 2)
            t2 = np.linspace(np.pi / 2, 3 * np.pi / 2, n // 2)
            pts = np.concatenate(
                [
                    np.stack([h + r * np.cos(t1), r * np.sin(t1)], 1),
                    np.stack([-h + r * np.cos(t2), r * np.sin(t2)], 1),
                ]
            )
        c, s = math.cos(self.angle), math.sin(self.angle)
        rot = np.array([[c, -s], [s, c]])
        return pts @ rot.T + np.asarray(self.center)


@dataclass
class Body:
    """A kinematic rigid body: its pose is prescribed (by a controller), never simulated."""

    name: str
    pose: tuple[float, float, float] = (0.0, 0.0, 0.0)  # x, y (m), theta (rad)
    shapes: list[Shape] = field(default_factory=list)

    def world_outlines(self, pose: tuple[float, float, float] | None = None) -> list[np.ndarray]:
        x, y, th = self.pose if pose is None else pose
        c, s = math.cos(th), math.sin(th)
        rot = np.array([[c, -s], [s, c]])
        return [sh.outline() @ rot.T + np.array([x, y]) for sh in self.shapes]


def open_box(inner_width: float, inner_height: float, wall: float) -> list[Shape]:
    """Open-top container: two side walls and a floor slab around the interior
    [-w/2, w/2] x [0, h] (body frame origin at the centre of the inner floor)."""
    if min(inner_width, inner_height, wall) <= 0:
        raise ValueError("open_box: inner_width, inner_height and wall must be > 0 m")
    w, h, t = inner_width, inner_height, wall
    side = (t / 2, (h + t) / 2)
    return [
        Shape("box", center=(-(w + t) / 2, (h - t) / 2), size=side),
        Shape("box", center=((w + t) / 2, (h - t) / 2), size=side),
        Shape("box", center=(0.0, -t / 2), size=(w / 2 + t, t / 2)),
    ]


@dataclass
class WaterBlock:
    """An axis-aligned block of water, in world coordinates or in a body's frame (``body`` set)."""

    lo: tuple[float, float]
    hi: tuple[float, float]
    body: str | None = None

    def __post_init__(self) -> None:
        if not all(h > l for l, h in zip(self.lo, self.hi)):
            raise ValueError(f"WaterBlock: hi {self.hi} must exceed lo {self.lo} on every axis")


@dataclass
class EnvSpec:
    """One environment: bodies (with colliders) and the water that starts in it."""

    bodies: list[Body] = field(default_factory=list)
    water: list[WaterBlock] = field(default_factory=list)

    def body_index(self, name: str) -> int:
        for i, b in enumerate(self.bodies):
            if b.name == name:
                return i
        raise KeyError(f"no body named {name!r}; bodies: {[b.name for b in self.bodies]}")


def sample_water(spec: EnvSpec, dx: float, ppc: int, rng: np.random.Generator, jitter: float = 0.25) -> np.ndarray:
    """Particles on a jittered sub-grid (``ppc`` per cell, +-``jitter`` of the sub-spacing) filling every
    water block; world frame."""
    k = int(round(math.sqrt(ppc)))
    h = dx / k
    out = []
    for blk in spec.water:
        (x0, y0), (x1, y1) = blk.lo, blk.hi
        nx, ny = max(1, int(round((x1 - x0) / h))), max(1, int(round((y1 - y0) / h)))
        gx, gy = np.meshgrid(
            (np.arange(nx) + 0.5) * (x1 - x0) / nx + x0, (np.arange(ny) + 0.5) * (y1 - y0) / ny + y0, indexing="ij"
        )
        pts = np.stack([gx.ravel(), gy.ravel()], 1)
        if jitter > 0:
            pts += rng.uniform(-jitter * h, jitter * h, size=pts.shape)
        if blk.body is not None:
            x, y, th = spec.bodies[spec.body_index(blk.body)].pose
            c, s = math.cos(th), math.sin(th)
            pts = pts @ np.array([[c, -s], [s, c]]).T + np.array([x, y])
        out.append(pts)
    return np.concatenate(out, 0).astype(np.float32) if out else np.zeros((0, 2), np.float32)
