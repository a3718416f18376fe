"""Where a planner call's time goes, on the experiment's own batches:
``python -m benchmarks.planner_profile --mde CHECKPOINT [--reference-commit SHA] [--out FILE] [overrides]``.

Why: planning is a third of the main job, and a propagation is a chain of small batched calls
(the learned model, the known-geometry contact check, the MDE) driven by OMPL's C++ loop. This
runs the batches :mod:`benchmarks.planner_pool` builds (the run's test plans and one training
chunk, in-process) and reports:

* propagations (model rows) per second, with the model called through its numpy path (the
  planner's default for a CPU model with ``predict_np``) and through torch (what a model without a
  numpy path costs), and for an ensemble also through its members' numpy paths one at a time (what
  stacking the members' weights into one matmul per layer buys), timed alternately in one process,
  medians of ``--repeat``; whether the plans agree;
* one profiled pass per path (``cProfile``): the share of the planning time spent in the learned
  model, the contact check (``sim.contact.ContactPredictor.first_contact``), the MDE and the
  rest (OMPL's loop, the propagator's bookkeeping, the profiler's own overhead).

With ``--reference-commit SHA`` it instead compares today's tree with that commit in one run: the
commit is checked out with ``git worktree add`` into a temporary folder, and each tree plans the same
batches in a process of its own (:mod:`benchmarks.planner_timer`), rounds alternating between them
(the machine's speed drifts 2-3x between hours; alternate rounds see the same drift). It reports each
tree's propagations per second (medians of ``--repeat``), their ratio, whether the plans are identical,
and the profiled shares of today's numpy path.
"""

from __future__ import annotations

import argparse
import copy
import cProfile
import json
import os
import pstats
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Sequence

from benchmarks._cli import report
from benchmarks.planner_pool import add_batch_arguments, check_batch_arguments, experiment_batches, fingerprint
from planner.pool import PlanPool
from planner.results import CandidateSet

#: profiled functions whose cumulative time makes each part (file suffix, function name)
PARTS = {
    "contact check": [("sim/contact.py", "first_contact")],
    "learned model": [
        ("dynamics/model.py", "predict_np"),
        ("dynamics/model.py", "predict"),
        ("dynamics/ensemble.py", "predict_np"),
    ],
    "MDE": [("planner/rrt.py", "deviation")],
}
TOTAL = ("planner/rrt.py", "_solve_with_ompl")
ROOT = Path(__file__).resolve().parents[1]


def _propagations(results: list) -> int:
    runs = [x for r in results for x in (r.runs if isinstance(r, CandidateSet) else [r])]
    return sum(int(x.stats.propagations) for x in runs)


def _cumulative(stats: pstats.Stats, keys: list[tuple[str, str]]) -> float:
    total = 0.0
    for (path, _line, name), (_cc, _nc, _tt, ct, _callers) in stats.stats.items():  # type: ignore[attr-defined]
        if any(path.endswith(p) and name == n for p, n in keys):
            total += ct
    return total


class _TorchPath:
    """The model without its numpy path, so that the planner calls it through torch."""

    def __init__(self, model: Any) -> None:
        self.model = model

    def predict(self, states: Any, actions: Any) -> Any:
        return self.model.predict(states, actions)


class _MembersOneByOne:
    """An ensemble whose numpy path averages its members' own numpy paths one at a time (no stacked weights)."""

    def __init__(self, ensemble: Any) -> None:
        self.ensemble = ensemble

    def predict(self, states: Any, actions: Any) -> Any:
        return self.ensemble.predict(states, actions)

    def predict_np(self, states: Any, actions: Any) -> Any:
        members = self.ensemble.members
        out = members[0].predict_np(states, actions)
        for m in members[1:]:
            out = out + m.predict_np(states, actions)
        return out / len(members)


def _path_models(dyn: Any) -> dict[str, Any]:
    """The model as each timed path sees it (the contact wrapper, when there is one, kept outermost)."""
    import dynamics

    inner = dyn.model if isinstance(dyn, dynamics.ContactAwareDynamics) else dyn

    def wrap(m: Any) -> Any:
        if inner is dyn:
            return m
        outer = copy.copy(dyn)
        outer.model = m
        return outer

    models = {"numpy": dyn, "torch": _TorchPath(dyn)}
    if isinstance(inner, dynamics.DynamicsEnsemble):
        models["members"] = wrap(_MembersOneByOne(inner))
    return models


def _shares(pool: PlanPool, batches: dict[str, list], mde: Any) -> dict[str, float]:
    """One profiled pass over every batch: each part's share of the planning time."""
    prof = cProfile.Profile()
    prof.enable()
    for reqs in batches.values():
        pool.run(reqs, mde)
    prof.disable()
    st = pstats.Stats(prof)
    total = _cumulative(st, [TOTAL])
    parts = {k: _cumulative(st, v) / total for k, v in PARTS.items()}
    parts["OMPL loop, bookkeeping, profiler"] = 1.0 - sum(parts.values())
    return parts


def run(
    overrides: Sequence[str] = (), mde_path: str | None = None, seed: int = 0, iteration: int = 0, repeat: int = 2
) -> dict[str, Any]:
    from active.run import compose_config
    from mde.grouped import GroupedMDE

    cfg = compose_config(["experiment=quick", *overrides])
    dyn, planner_cfg, batches, info = experiment_batches(cfg, seed, iteration)
    mde = GroupedMDE.load(mde_path) if mde_path else None
    pools = {p: PlanPool(m, planner_cfg, workers=1) for p, m in _path_models(dyn).items()}
    pools["numpy"].run(batches["test"][:1], mde)  # lazy torch / OMPL set-up
    paths = tuple(pools)
    times = {p: {b: [] for b in batches} for p in paths}
    prints: dict[str, dict[str, Any]] = {p: {} for p in paths}
    props: dict[str, int] = {}
    for rep in range(repeat):  # alternating: a drift of the machine's speed hits both paths alike
        for path in paths if rep % 2 == 0 else paths[::-1]:
            for name, reqs in batches.items():
                t = time.perf_counter()
                got = pools[path].run(reqs, mde)
                times[path][name].append(time.perf_counter() - t)
                prints[path][name] = [fingerprint(r) for r in got]
                props[name] = _propagations(got) if path == "numpy" else props.get(name, 0)
    shares = {path: _shares(pools[path], batches, mde) for path in paths}
    result: dict[str, Any] = {
        "setup": info,
        "mde": mde_path,
        "overrides": list(overrides),
        "seed": seed,
        "iteration": iteration,
        "batches": {},
        "shares": shares,
    }
    for name, reqs in batches.items():
        med = {p: statistics.median(times[p][name]) for p in paths}
        result["batches"][name] = {
            "requests": len(reqs),
            "propagations_numpy_path": props[name],
            "seconds": med,
            "seconds_all": {p: times[p][name] for p in paths},
            "propagations_per_s_numpy_path": props[name] / med["numpy"],
            **{f"speedup_numpy_over_{p}": med[p] / med["numpy"] for p in paths[1:]},
            **{f"same_plans_{p}": prints["numpy"][name] == prints[p][name] for p in paths[1:]},
        }
    return result


class _Timer:
    """A :mod:`benchmarks.planner_timer` process planning the batches with the code of ``tree``."""

    def __init__(self, tree: Path, args: dict[str, Any]) -> None:
        env = {**os.environ, "PYTHONPATH": str(tree)}  # -P: not the script's folder (benchmarks/planner.py)
        script = str(ROOT / "benchmarks" / "planner_timer.py")
        self.proc = subprocess.Popen(
            [sys.executable, "-P", script, json.dumps(args)], cwd=ROOT, env=env, stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        self._read(lambda line: line.strip() == "ready")

    def _read(self, done: Any) -> str:
        for line in self.proc.stdout:  # type: ignore[union-attr]
            if done(line):
                return line
        raise RuntimeError(f"planner timer exited with {self.proc.wait()} (its stderr is above)")

    def time(self, batch: str) -> dict[str, Any]:
        """Plan ``batch`` once: seconds, propagations and the plans' digest."""
        self.proc.stdin.write(batch + "\n")  # type: ignore[union-attr]
        self.proc.stdin.flush()  # type: ignore[union-attr]
        return json.loads(self._read(lambda line: line.startswith("{")))

    def close(self) -> None:
        self.proc.stdin.close()  # type: ignore[union-attr]
        self.proc.wait()


def compare_with_reference(
    commit: str, overrides: Sequence[str], mde_path: str | None, seed: int, iteration: int, repeat: int
) -> dict[str, Any]:
    """Today's tree against ``commit`` (checked out in a temporary worktree), rounds alternating."""
    sha = subprocess.run(["git", "rev-parse", commit], cwd=ROOT, check=True, capture_output=True, text=True)
    sha_s = sha.stdout.strip()
    args = {"overrides": list(overrides), "mde": mde_path and str(Path(mde_path).resolve()), "seed": seed}
    args["iteration"] = iteration
    with tempfile.TemporaryDirectory(prefix="planner-ref-") as tmp:
        ref_tree = Path(tmp) / "ref"
        subprocess.run(["git", "worktree", "add", "--detach", str(ref_tree), sha_s], cwd=ROOT, check=True)
        try:
            timers = {"reference": _Timer(ref_tree, args), "current": _Timer(ROOT, args)}
            got: dict[str, dict[str, list[dict]]] = {t: {"test": [], "train": []} for t in timers}
            for rep in range(repeat):
                for side in ("reference", "current") if rep % 2 == 0 else ("current", "reference"):
                    for batch in ("test", "train"):
                        got[side][batch].append(timers[side].time(batch))
            for t in timers.values():
                t.close()
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(ref_tree)], cwd=ROOT, check=False)
    batches = {}
    for batch in ("test", "train"):
        med = {side: statistics.median(x["seconds"] for x in got[side][batch]) for side in got}
        props = {side: got[side][batch][0]["propagations"] for side in got}
        batches[batch] = {
            "seconds": med,
            "seconds_all": {side: [x["seconds"] for x in got[side][batch]] for side in got},
            "propagations_per_s": {side: props[side] / med[side] for side in got},
            "speedup": med["reference"] / med["current"],
            "same_plans": len({x["plans"] for side in got for x in got[side][batch]}) == 1,
        }
    return {"reference_commit": sha_s, "batches": batches}


def run_reference(
    commit: str, overrides: Sequence[str] = (), mde_path: str | None = None, seed: int = 0, iteration: int = 0,
    repeat: int = 2,
) -> dict[str, Any]:  # fmt: skip
    """:func:`compare_with_reference`, then one profiled pass of today's numpy path (the time breakdown)."""
    from active.run import compose_config
    from mde.grouped import GroupedMDE

    result = compare_with_reference(commit, overrides, mde_path, seed, iteration, repeat)
    cfg = compose_config(["experiment=quick", *overrides])
    dyn, planner_cfg, batches, info = experiment_batches(cfg, seed, iteration)
    mde = GroupedMDE.load(mde_path) if mde_path else None
    pool = PlanPool(dyn, planner_cfg, workers=1)
    pool.run(batches["test"][:1], mde)
    result.update(setup=info, mde=mde_path, overrides=list(overrides), seed=seed, iteration=iteration)
    result["shares"] = _shares(pool, batches, mde)
    return result


def format_reference_table(r: dict[str, Any]) -> str:
    """The table of :func:`run_reference`."""
    lines = [
        f"setup: {r['setup']}",
        f"MDE: {r['mde']}",
        f"reference: {r['reference_commit']}",
        "",
        f"{'batch':<8} {'ref prop/s':>11} {'new prop/s':>11} {'ref s':>8} {'new s':>8} {'ratio':>6}  same plans",
    ]
    for name, b in r["batches"].items():
        pps, sec = b["propagations_per_s"], b["seconds"]
        lines.append(
            f"{name:<8} {pps['reference']:>11.0f} {pps['current']:>11.0f} {sec['reference']:>8.2f} "
            f"{sec['current']:>8.2f} {b['speedup']:>6.2f}  {'yes' if b['same_plans'] else 'no'}"
        )
    lines += ["", "share of today's planning time (profiled pass, both batches)"]
    lines += [f"{n:<34} {v:>6.2f}" for n, v in r["shares"].items()]
    return "\n".join(lines)


def format_table(r: dict[str, Any]) -> str:
    paths = list(r["shares"])
    others = paths[1:]
    lines = [
        f"setup: {r['setup']}",
        f"MDE: {r['mde']}",
        "",
        f"{'batch':<8} {'propagations':>12} "
        + " ".join(f"{p + ' path s':>15}" for p in paths)
        + " "
        + " ".join(f"{'x over ' + p:>14}" for p in others)
        + f" {'prop/s (numpy)':>15}  same plans",
    ]
    for name, b in r["batches"].items():
        lines.append(
            f"{name:<8} {b['propagations_numpy_path']:>12} "
            + " ".join(f"{b['seconds'][p]:>15.2f}" for p in paths)
            + " "
            + " ".join(f"{b[f'speedup_numpy_over_{p}']:>14.2f}" for p in others)
            + f" {b['propagations_per_s_numpy_path']:>15.0f}  "
            + ", ".join(f"{p}: {'yes' if b[f'same_plans_{p}'] else 'no'}" for p in others)
        )
    lines += ["", "share of planning time (profiled pass, both batches)"]
    names = list(next(iter(r["shares"].values())))
    lines.append(f"{'part':<34} " + " ".join(f"{p + ' path':>12}" for p in paths))
    for n in names:
        lines.append(f"{n:<34} " + " ".join(f"{r['shares'][p][n]:>12.2f}" for p in paths))
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.planner_profile", description=__doc__.split("\n\n")[0])
    add_batch_arguments(ap, iteration=3)
    ap.add_argument(
        "--reference-commit",
        metavar="SHA",
        default=None,
        help="compare today's tree with this commit, alternating rounds (instead of the model paths)",
    )
    args = ap.parse_args(argv)
    check_batch_arguments(ap, args)
    if args.reference_commit:
        r = run_reference(args.reference_commit, args.overrides, args.mde, args.seed, args.iteration, args.repeat)
        report(format_reference_table(r), r, args.out)
        return 0
    r = run(args.overrides, mde_path=args.mde, seed=args.seed, iteration=args.iteration, repeat=args.repeat)
    report(format_table(r), r, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
