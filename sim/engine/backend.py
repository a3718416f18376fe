"""One place that initialises Taichi, so that every solver in a process agrees on the arch."""

from __future__ import annotations

import platform

import numpy as np
import taichi as ti

from .config import ARCHES, ConfigError

try:
    from numpy._core._multiarray_umath import __cpu_features__ as _CPU_FEATURES
except ImportError:  # numpy < 2
    from numpy.core._multiarray_umath import __cpu_features__ as _CPU_FEATURES

_current: str | None = None


def init_taichi(arch: str = "cpu", *, debug: bool = False, kernel_profiler: bool = False) -> str:
    """Initialise Taichi once per process for ``arch`` (cpu | gpu | auto); returns the arch in use.

    ``gpu`` fails loudly when no GPU backend can start (Taichi itself would silently fall back to
    the CPU, which would make a GPU benchmark meaningless). Re-initialising with another arch resets
    Taichi: solvers built before are invalid afterwards. ``kernel_profiler``: Taichi times every
    offloaded task (one per top-level loop of a kernel; ``benchmarks.sim_profile``); only on the
    first initialisation of a process.
    """
    global _current
    if arch not in ARCHES:
        raise ConfigError(f"sim.arch = {arch!r} is invalid: allowed one of {ARCHES}")
    if _current is not None and arch in (_current, "auto"):
        return _current
    if _current is not None:
        ti.reset()
    kwargs = dict(default_fp=ti.f32, debug=debug, log_level=ti.WARN, kernel_profiler=kernel_profiler)
    if arch == "cpu":
        # no fast math: IEEE arithmetic without contraction into FMA or reassociation, so that the
        # rounding does not depend on the host's vector width (it runs 7-20 % slower than with fast math)
        ti.init(arch=ti.cpu, fast_math=False, **kwargs)
    else:
        ti.init(arch=ti.gpu, **kwargs)
        got = ti.lang.impl.current_cfg().arch
        if got in (ti.x64, ti.arm64):
            if arch == "gpu":
                ti.reset()
                _current = None
                raise ConfigError(
                    "sim.arch = 'gpu' but no GPU backend (CUDA, Vulkan, Metal) is available: use arch=cpu or arch=auto"
                )
    got = ti.lang.impl.current_cfg().arch
    _current = "cpu" if got in (ti.x64, ti.arm64) else "gpu"
    return _current


def current_arch() -> str | None:
    return _current


def cpu_fingerprint() -> str:
    """The machine, its vector instruction sets and the numpy and Taichi versions: what decides the CPU
    solver's floating-point results.

    Why: under Taichi's fast math the lane width (AVX2 or AVX-512) and FMA change the rounding, and numpy's
    vectorised sin / cos / power differ between instruction sets and releases. The CPU solver runs without
    fast math and the host-side schedule uses libm's scalar functions, which should make results the same on
    every x86-64 CPU with the same libraries; bit-for-bit comparisons still require the same fingerprint (the
    shipped dataset records the one that made it; tests/test_dynamics_shipped.py compares states made on
    another kind of CPU within a tolerance)."""
    keep = ("AVX", "AVX2", "FMA3", "AVX512F", "AVX512_SKX", "ASIMD", "SVE")
    return " ".join(
        [platform.machine()]
        + [k for k in keep if _CPU_FEATURES.get(k)]
        + [f"numpy {np.__version__}", "taichi " + ".".join(map(str, ti.__version__))]
    )
