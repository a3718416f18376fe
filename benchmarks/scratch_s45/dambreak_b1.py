"""Scratch (session 45): the 3D dam break at B = 1 stepped in frames of 10 substeps after 300 substeps of collapse; prints
particle-substeps/s and a position checksum (equal checksums: equal arithmetic). Used by transfers_ab.sh (one thread:
TI_CPU_MAX_NUM_THREADS=1) and for perf profiles.

    PYTHONPATH=. python benchmarks/scratch_s45/dambreak_b1.py [SUBSTEPS]
"""
import os, sys, time
os.environ.setdefault("TI_CPU_MAX_NUM_THREADS", "2")
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "peers"))
import dambreak_common as C
import taichi as ti
from sim.config import SimConfig
from sim.mpm import MPMSolver
from sim.scene import EnvSpec, WaterBlock
dx = 0.01; dt = C.dt_for(dx); lo, hi = C.column_box(dx)
cfg = SimConfig(dim=3, domain=C.domain_for(dx), dx=dx, dt=dt, rho=C.RHO, sound_speed=C.SOUND_SPEED, gravity=C.G,
                friction=0.0, ppc=C.PPC_1D**3, n_envs=1, max_particles=C.expected_particles(dx), wall_cells=C.WALL_CELLS,
                jitter=0.0)
specs = [EnvSpec(water=[WaterBlock(lo, hi)])]
s = MPMSolver(cfg); s.reset(specs); s.step(1); ti.sync(); s.reset(specs)
n = int(sys.argv[1]) if len(sys.argv) > 1 else 1000
s.step(300); ti.sync()   # let the column start to collapse
t = time.perf_counter()
for _ in range(n // 10):
    s.step(10)
ti.sync(); el = time.perf_counter() - t
x = s.positions(0)
print(f"{n} substeps {el:.2f} s {16000*n/el:.3g} p-sub/s checksum {float(x.astype('float64').sum()):.10f}")
