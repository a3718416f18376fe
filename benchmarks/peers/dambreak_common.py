"""The 3D dam-break scene shared by the peer benchmarks (standard library + numpy only, so that it
imports both in the project's Python and in the Genesis virtual environment).

Scene (every size): a closed box tank whose *interior* is L x H x W = 0.50 x 0.25 x 0.10 m (length
along x, height along the up axis, width across), with walls ``WALL_CELLS`` grid cells thick on every
side, so the simulation domain is the interior plus 2 * 3 dx per axis. A water column of base a =
0.10 m, height 2a = 0.20 m and the full tank width W = 0.10 m stands in the corner at x = 0 (a
Martin & Moyce n^2 = 2 column, extruded across the tank, so the front is the 2D experiment's). At
8 particles per cell (2 per cell and axis) that is 0.1 * 0.2 * 0.1 / dx^3 * 8 particles: 16,000 at
dx = 10 mm, 128,000 at dx = 5 mm. Water: rho = 1000 kg/m^3, bulk modulus K = rho c^2 with c = 12 m/s
(the project's default), no viscosity, free-slip walls, g = 9.81 m/s^2.

Coordinates in this module and in every JSON are the project's: x along the tank, y up, z across.
Genesis is z-up; its script maps (x, y, z)_ours = (x, z, y)_genesis.
"""

from __future__ import annotations

import json
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

G = 9.81
INTERIOR = (0.50, 0.25, 0.10)  # m: length (x), height (y, up), width (z)
COLUMN = (0.10, 0.20, 0.10)  # m: base a (x), height 2a (y), width (z) = full tank width
A = COLUMN[0]
WALL_CELLS = 3  # both solvers: walls 3 cells in from the domain edge (Genesis pads its grid by 3 dx)
PPC_1D = 2  # particles per cell and axis: 8 per cell
RHO = 1000.0
SOUND_SPEED = 12.0
BULK = RHO * SOUND_SPEED**2  # Pa
SUBSTEPS_PER_FRAME = 10  # substeps per Genesis scene.step(); our solver steps the same chunks
T_END = 3.0  # dimensionless end time T = t sqrt(2 g / a)
T_SAMPLES = tuple(round(0.2 * i, 1) for i in range(16))  # 0.0, 0.2, ..., 3.0
REPO = Path(__file__).resolve().parents[2]


def dt_for(dx: float) -> float:
    """Substep: 2e-2 dx (Genesis's suggested MPM substep; 2e-4 s at 10 mm, 1e-4 s at 5 mm), well
    inside our acoustic bound 0.5 dx / c."""
    return round(2e-2 * dx, 12)


def domain_for(dx: float) -> tuple[float, float, float]:
    """Domain (x, y up, z): tank interior plus the walls on both sides."""
    return tuple(round(L + 2 * WALL_CELLS * dx, 9) for L in INTERIOR)


def column_box(dx: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(lo, hi) corners of the water column in the domain frame (x, y up, z)."""
    w = WALL_CELLS * dx
    lo = (w, w, w)
    hi = tuple(round(w + c, 9) for c in COLUMN)
    return lo, hi


def expected_particles(dx: float) -> int:
    return int(np.prod([round(c / (dx / PPC_1D)) for c in COLUMN]))


def t_of(T: float) -> float:
    return T / math.sqrt(2 * G / A)


def frames_to_end(dt: float, t_end_T: float = T_END) -> int:
    """Frames (chunks of SUBSTEPS_PER_FRAME substeps) to reach dimensionless time t_end_T."""
    return int(math.ceil(t_of(t_end_T) / (dt * SUBSTEPS_PER_FRAME) - 1e-9))


def sample_frames(dt: float, n_frames: int) -> list[int]:
    """Frame indices nearest to the T_SAMPLES (those within n_frames), without duplicates."""
    out = []
    for T in T_SAMPLES:
        f = int(round(t_of(T) / (dt * SUBSTEPS_PER_FRAME)))
        if f <= n_frames and f not in out:
            out.append(f)
    return out


def front_metrics(pos: np.ndarray, dx: float) -> dict:
    """Surge front of one environment's particles (n, 3) in (x, y up, z), measured from the inner
    wall at x = 3 dx: p99 = 99th percentile of x over all particles; max_low = furthest particle
    within 0.1 a of the floor (benchmarks/validate.py's definition, the one to compare with Martin & Moyce)."""
    w = WALL_CELLS * dx
    x = pos[:, 0] - w
    low = pos[:, 1] < w + 0.1 * A
    return {"p99": float(np.percentile(x, 99.0)), "max_low": float(x[low].max()) if low.any() else float("nan")}


def new_front_record() -> dict:
    return {"frame": [], "t": [], "T": [], "front_p99_m": [], "front_max_low_m": [], "Z_p99": [], "Z_max_low": []}


def add_front(rec: dict, frame: int, dt: float, pos: np.ndarray, dx: float) -> None:
    t = frame * SUBSTEPS_PER_FRAME * dt
    m = front_metrics(pos, dx)
    rec["frame"].append(frame)
    rec["t"].append(t)
    rec["T"].append(t * math.sqrt(2 * G / A))
    rec["front_p99_m"].append(m["p99"])
    rec["front_max_low_m"].append(m["max_low"])
    rec["Z_p99"].append(m["p99"] / A)
    rec["Z_max_low"].append(m["max_low"] / A)


def machine_info() -> dict:
    info = {
        "host": platform.node(),
        "machine": platform.machine(),
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
        "loadavg": list(os.getloadavg()),
    }
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                info["cpu"] = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return info


def scene_record(dx: float) -> dict:
    lo, hi = column_box(dx)
    return {
        "interior_m": list(INTERIOR),
        "domain_m": list(domain_for(dx)),
        "wall_cells": WALL_CELLS,
        "column_lo_m": list(lo),
        "column_hi_m": list(hi),
        "a_m": A,
        "particles_per_cell": PPC_1D**3,
        "rho": RHO,
        "sound_speed_m_s": SOUND_SPEED,
        "bulk_modulus_Pa": BULK,
        "g": G,
        "axes": "x along the tank, y up, z across (Genesis: z up, mapped)",
    }


def write_json(path: str | Path, obj: dict) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(obj, indent=1))
    os.replace(tmp, path)


class Timer:
    """Accumulates wall time of the timed stepping calls only."""

    def __init__(self, sync=None):
        self.seconds = 0.0
        self.sync = sync or (lambda: None)

    def __enter__(self):
        self.sync()
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.sync()
        self.seconds += time.perf_counter() - self._t0
