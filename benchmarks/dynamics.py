"""Inference throughput of the dynamics model on this CPU (what the planner pays per propagation).

    python -m benchmarks.dynamics [--out FILE] [--untrained] [--config-name NAME] [key=value ...]

Times ``predict`` (torch, batched, input checks included) and the numpy path (``predict_np`` /
``predict_one``) at batch 1 (a move and a pour separately) and batch 1024 (half moves, half
pours), with 1 torch thread (the
planner's setting) and with torch's default thread count. Uses the cached checkpoint of the
config if there is one, else (or with ``--untrained``) a freshly initialised network of the same
architecture: the cost does not depend on the weights (an ensemble: one member; it costs n of
them). Best of several repeats; prints a table
and writes JSON.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

import safeio
from dynamics.model import LearnedDynamics


def _time(fn: Callable[[], Any], min_seconds: float = 0.2, repeats: int = 5) -> float:
    """Best per-call seconds over ``repeats`` rounds of at least ``min_seconds`` each."""
    fn()
    n = 1
    while True:
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        dt = time.perf_counter() - t0
        if dt >= min_seconds / 4:
            break
        n *= 4
    n = max(1, int(n * min_seconds / max(dt, 1e-9)))
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t0) / n)
    return best


def inputs(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Plausible states and actions (half moves, half pours) in the world's ranges."""
    rng = np.random.default_rng(seed)
    vc = rng.uniform(0, 1, n)
    s = np.column_stack(
        [rng.uniform(0.1, 0.52, n), rng.uniform(0.06, 0.36, n), np.zeros(n), vc, rng.uniform(0, 1, n) * (1 - vc)]
    )
    pour = np.arange(n) % 2 == 1
    a = np.column_stack(
        [
            pour.astype(float),
            np.where(pour, rng.uniform(0, 2.2, n), rng.uniform(0.1, 0.52, n)),
            np.where(pour, rng.uniform(0, 1, n), rng.uniform(0.06, 0.36, n)),
        ]
    )
    return s, a


def bench(
    model: LearnedDynamics,
    threads: list[int],
    batches: tuple[int, ...] = (1, 1024),
    min_seconds: float = 0.2,
    repeats: int = 5,
) -> list[dict]:
    rows = []
    prev = torch.get_num_threads()
    try:
        for th in threads:
            torch.set_num_threads(th)
            for n in batches:
                s, a = inputs(max(n, 2))
                if n == 1:  # one move and one pour, timed separately (the pour's inputs cost more)
                    cases = [("move", s[:1], a[:1]), ("pour", s[1:2], a[1:2])]
                else:
                    cases = [("mixed", s, a)]
                paths = {}
                for skill, sc, ac in cases:
                    st, at = torch.tensor(sc, dtype=torch.float32), torch.tensor(ac, dtype=torch.float32)
                    paths[f"predict (torch) {skill}"] = lambda st=st, at=at: model.predict(st, at)
                    paths[f"predict_np (numpy) {skill}"] = lambda sc=sc, ac=ac: model.predict_np(sc, ac)
                    if n == 1:
                        paths[f"predict_one (numpy) {skill}"] = lambda sc=sc, ac=ac: model.predict_one(sc[0], ac[0])
                for name, fn in paths.items():
                    if "numpy" in name and th != threads[0]:
                        continue  # numpy does not use torch's threads
                    sec = _time(fn, min_seconds, repeats)
                    rows.append(
                        {
                            "path": name,
                            "batch": n,
                            "torch_threads": th if "torch" in name else None,
                            "us_per_call": sec * 1e6,
                            "transitions_per_s": n / sec,
                        }
                    )
    finally:
        torch.set_num_threads(prev)
    return rows


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.dynamics", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--out", default=".cache/dynamics/bench.json", help="JSON output file")
    ap.add_argument("--untrained", action="store_true", help="time a freshly initialised network")
    ap.add_argument("--config-name", default="default")
    ap.add_argument("--min-seconds", type=float, default=0.2, help="length of one timing round")
    ap.add_argument("--repeats", type=int, default=5, help="timing rounds (the best is reported)")
    ap.add_argument("overrides", nargs="*", help="Hydra-style overrides of configs/dynamics")
    args = ap.parse_args(argv)
    from dynamics.config import ensemble_member
    from dynamics.evaluate import compose_config
    from dynamics.train import cache_paths

    cfg = compose_config(args.config_name, args.overrides)
    if cfg.model.ensemble > 1:  # an ensemble costs n of its members: time one
        cfg = ensemble_member(cfg, 0)
    ckpt = cache_paths(cfg)["checkpoint"]
    if ckpt.is_file() and not args.untrained:
        model, source = LearnedDynamics.load(ckpt), str(ckpt)
    else:
        torch.manual_seed(0)
        model = LearnedDynamics(cfg.model)
        source = "untrained" if args.untrained else "untrained (no cached checkpoint)"
    default_threads = torch.get_num_threads()
    threads = sorted({1, default_threads})
    rows = bench(model, threads, min_seconds=args.min_seconds, repeats=args.repeats)
    n_params = sum(p.numel() for p in model.parameters())
    print(
        f"dynamics model: {source}; hidden {list(model.cfg.hidden)} per skill, {n_params} parameters; "
        f"CPU {platform.processor() or platform.machine()} x {os.cpu_count()} cores, torch {torch.__version__}"
    )
    print(f"{'path':28s} {'batch':>6s} {'threads':>8s} {'us/call':>12s} {'transitions/s':>15s}")
    for r in rows:
        th = "-" if r["torch_threads"] is None else str(r["torch_threads"])
        print(f"{r['path']:28s} {r['batch']:6d} {th:>8s} {r['us_per_call']:12.1f} {r['transitions_per_s']:15.0f}")
    result = {
        "model": source,
        "hidden": list(model.cfg.hidden),
        "parameters": n_params,
        "rows": rows,
        "cpu_count": os.cpu_count(),
        "torch": torch.__version__,
        "machine": platform.machine(),
        "load_average": os.getloadavg(),
    }
    out = Path(args.out)
    safeio.write_json(out, result, indent=1)
    print(f"wrote {out}")
    return result


if __name__ == "__main__":
    main()
