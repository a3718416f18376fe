"""Lockstep: every (method, seed) of a run advances one iteration at a time, and each round's planner
calls and simulations are batched across the runs.

Why: a run alone executes 6-10 trajectories per simulation, where the batched simulator is least
efficient (on the CPU B = 8 gives half the particle-substeps/s of B = 32), and plans a handful of
problems per call. Each run's iteration is a generator (:meth:`active.loop.MethodRun.iteration_steps`)
that yields what it waits for; a round serves every run's planner calls in one pool batch (each run
with its own MDE) and their simulations in one executor call. A run's results do not depend on the
others': all randomness is derived from (seed, purpose, iteration, index), a trajectory samples its
water as the slot it has when its run is alone, and environments do not interact. So on the CPU a
run gives in lockstep exactly the results it gives alone (``tests/test_active_run.py``), and a
killed lockstep run resumes each (method, seed) from its own last saved iteration.
"""

from __future__ import annotations

import logging
import time
from typing import Sequence

from tqdm.auto import tqdm

from planner.pool import PlanPool
from sim.execute import PouringExecutor

from .loop import MethodRun
from .needs import PlanNeed, SimNeed, execute_needs

log = logging.getLogger(__name__)


def round_line(it: int, iterations: int, n_runs: int, seconds: float, mean_seconds: float) -> str:
    """The log line after round ``it`` (0-based): its time and the time left at this process's mean pace, so that a
    run of hours (the paper protocol) says in its log when it will end, with or without the progress bar."""
    left = iterations - it - 1
    eta = left * mean_seconds
    when = f"{eta / 3600:.1f} h" if eta >= 5400 else f"{eta / 60:.0f} min"
    tail = f"; {left} round(s) left, about {when} at this pace" if left else "; all rounds done"
    return f"lockstep round {it + 1}/{iterations}: {n_runs} run(s) in {seconds:.0f} s{tail}"


def run_lockstep(runs: Sequence[MethodRun], pool: PlanPool, executor: PouringExecutor, progress: bool = True) -> None:
    """Advance ``runs`` (all of one experiment config) round by round to ``exp.iterations``.

    A round is one iteration of every run that has not finished it. While any run waits for planner
    calls, those are served (all together) first; simulations wait until no run needs the planner,
    so that runs which do not plan (random actions) join the others' simulation batch.
    """
    runs = list(runs)
    if not runs:
        return
    iterations = runs[0].ctx.exp.iterations
    first = min(r.completed for r in runs)
    bar = tqdm(
        range(first, iterations),
        disable=not progress,
        desc=f"lockstep: {len(runs)} runs",
        unit="round",
        initial=first,
        total=iterations,
    )
    times: list[float] = []
    for it in bar:
        pool.start()  # worker start-up (first round only) is not planning time
        t0 = time.perf_counter()
        steps = {k: r.iteration_steps(it) for k, r in enumerate(runs) if r.completed == it}
        pending: dict[int, PlanNeed | SimNeed] = {}
        rows: dict[int, dict] = {}

        for k in steps:
            _advance(steps, pending, rows, k, None)
        while pending:
            plans = [(k, n) for k, n in pending.items() if isinstance(n, PlanNeed)]
            if plans:
                results = pool.run_groups([(n.requests, n.mde) for _, n in plans], errors="record")
                served = [k for k, _ in plans]
            else:
                served = list(pending)
                results = execute_needs(executor, [pending[k] for k in served])
            for k, res in zip(served, results):
                _advance(steps, pending, rows, k, res)
        for k in steps:
            runs[k].finish_iteration(it, rows[k])
        times.append(time.perf_counter() - t0)
        log.info(round_line(it, iterations, len(steps), times[-1], sum(times) / len(times)))


def _advance(steps: dict, pending: dict, rows: dict, k: int, result: list | None) -> None:
    """Send run ``k`` the result it waited for (None: start it); record what it waits for next, or its row."""
    try:
        pending[k] = next(steps[k]) if result is None else steps[k].send(result)
    except StopIteration as done:
        pending.pop(k, None)
        rows[k] = done.value
