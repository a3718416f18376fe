"""The lockstep runner against the sequential one, on the same experiment:
``python -m benchmarks.lockstep [--out benchmarks/lockstep.json] [overrides]``.

Why: ``runner=lockstep`` batches each round's planner calls and simulations over every method and
seed of a run (``active.lockstep``), where ``runner=sequential`` simulates 6-10 trajectories at a time.
This runs the same config both ways into temporary directories, sequential first, after the dynamics
model is loaded once (trained on first use, not timed), and reports the wall time of each, the
time the runs' results attribute to planning, simulation, MDE fits and tests, and whether the two
gave the same results (they must, on the CPU). Extra arguments are Hydra overrides of the run's config
(default: the README's main job, ``experiment=quick``), e.g. ``experiment.iterations=2 seeds=[0,1]``.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

from benchmarks._cli import report

PHASES = ("plan_seconds", "sim_seconds", "fit_seconds", "test_seconds")


def _rows(out: Path) -> dict[str, list[dict]]:
    """Each run's results.csv rows, by its folder relative to the run directory (``[seed<s>/]<method>``)."""
    from active.io import read_csv

    return {str(p.parent.relative_to(out)): read_csv(p) for p in sorted(out.rglob("results.csv"))}


def _comparable(rows: dict) -> dict:
    from active.loop import TIMING_FIELDS

    return {k: [{f: v for f, v in r.items() if f not in TIMING_FIELDS} for r in rs] for k, rs in rows.items()}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="write the result as JSON here")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of the run's config")
    args = ap.parse_args(argv)

    import dynamics
    from active.run import compose_config, run_experiment

    base = compose_config(list(args.overrides) + ["progress=false", "wandb.mode=disabled"])
    dynamics.load_or_train(base["dynamics"], world_cfg=base["world"], progress=False)  # cached before timing
    result: dict = {
        "overrides": list(args.overrides),
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
        "runners": {},
    }
    with tempfile.TemporaryDirectory(prefix="bench-lockstep-") as tmp:
        rows = {}
        for runner in ("sequential", "lockstep"):
            cfg = compose_config(list(args.overrides) + ["progress=false", "wandb.mode=disabled", f"runner={runner}"])
            out = Path(tmp) / runner
            t0 = time.perf_counter()
            run_experiment(cfg, out)
            wall = time.perf_counter() - t0
            rows[runner] = _rows(out)
            phases = {}
            for ph in PHASES:  # sequential: each run's own time; lockstep: a shared call counts once per round
                per_round: dict[int, list[float]] = {}
                for rs in rows[runner].values():
                    for r in rs:
                        per_round.setdefault(int(r["iteration"]), []).append(float(r[ph]))
                shared = runner == "lockstep" and ph != "fit_seconds"
                phases[ph] = sum(max(v) if shared else sum(v) for v in per_round.values())
            result["runners"][runner] = {"wall_s": wall, **{k: round(v, 1) for k, v in phases.items()}}
        result["identical_results"] = _comparable(rows["sequential"]) == _comparable(rows["lockstep"])
    seq, lock = result["runners"]["sequential"], result["runners"]["lockstep"]
    result["speedup"] = seq["wall_s"] / lock["wall_s"]
    lines = [
        f"runs: {len(rows['sequential'])} (method, seed) pairs; overrides {args.overrides}",
        f"{'runner':<11} {'wall s':>8} " + " ".join(f"{p.split('_')[0] + ' s':>8}" for p in PHASES),
    ]
    for name, r in result["runners"].items():
        lines.append(f"{name:<11} {r['wall_s']:8.1f} " + " ".join(f"{r[p]:8.1f}" for p in PHASES))
    lines.append(f"lockstep speedup {result['speedup']:.2f}x; identical results: {result['identical_results']}")
    report("\n".join(lines), result, args.out)
    return result


if __name__ == "__main__":
    main()
