"""Independent planner calls in worker processes, with exactly the results of planning in-process.

Why: the experiment plans many independent problems (N candidates per training problem, one plan
per test problem) while the simulator waits, and every planner run is single-threaded, so on a
multi-core machine the calls can run side by side. Each call is fully determined by its request
(start, goal, beta, d_max, seed, ...), the dynamics model, the MDE and the :class:`PlannerConfig`;
nothing depends on which process runs it or in which order, so a :class:`PlanPool` returns, in
request order, the results ``Planner(dynamics, mde, config).plan(...)`` / ``.plan_candidates(...)``
give in-process, bit for bit (see ``tests/test_planner_pool.py``). Bit-identity assumes the
config's ``torch_threads`` is set (the default 1): workers always run torch with that many
threads (1 when it is 0), and the parent does too while it plans.

How:

* ``workers <= 1``: plain in-process calls, no subprocess.
* ``workers > 1``: a persistent ``ProcessPoolExecutor`` with the **spawn** start method (the
  parent runs Taichi and OpenMP threads; a forked child could inherit locked mutexes), started
  on first use and reused until :meth:`PlanPool.close`. A candidate-set request is split into its
  N independent runs (same child seeds as :meth:`Planner.plan_candidates`, reassembled by
  :func:`planner.rrt.collect_candidates`), so that uneven run times balance over the workers.
  The dynamics model goes to each worker
  once (initializer). The MDE changes after each refit, so it is pickled once per batch into a
  private temporary file that each worker reads when its content digest changes (one copy per
  worker per refit, however many requests use it). Pickling keeps every tensor exactly; rebuilding
  from a state dict would refactorise the GP and could differ in the last bits.
* :meth:`PlanPool.run_groups` plans, in one batch, requests that use different MDEs (the lockstep
  runner: every (method, seed) has its own); each distinct MDE is published once per batch and
  workers keep the last few they read.
* Workers run one OpenMP / BLAS / torch thread each (two workers must not oversubscribe two
  cores) and ignore SIGINT: Ctrl-C stops the parent, which then terminates them.
* A request that raises in a worker raises the same exception in the parent (with the worker's
  traceback attached as its cause), for the first failing request in request order, as the
  sequential loop would; the batch's other running requests are waited for, pending ones dropped.
  With ``run(..., errors="record")`` a failing run is instead recorded as a run that found nothing
  (``stats.termination == "error"``, ``stats.error`` the message) and the batch goes on: how the
  experiment keeps going when one plan fails.
* A worker that dies (crash, out of memory: ``BrokenProcessPool``) or a pool that cannot start
  (e.g. a model that does not pickle) is logged as a warning and planning continues in-process
  for the rest of the run; since results do not depend on where they are computed, they do not
  change.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import logging
import multiprocessing
import os
import pickle
import shutil
import signal
import tempfile
import threading
import time
from collections import OrderedDict
from concurrent.futures import Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np
import torch

from .config import PlannerConfig
from .interfaces import DeviationEstimator, DynamicsModel
from .results import CandidateSet, PlannerStats, PlanResult
from .rrt import Planner, candidate_seeds, collect_candidates, run_seed_sequence, run_seeds

log = logging.getLogger(__name__)

#: ``workers: auto`` uses at most this many processes (planning batches rarely have more requests)
AUTO_MAX_WORKERS = 8
#: thread-count variables every worker gets (set before spawning, so that libraries read them at load)
_THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
_KINDS = ("plan", "candidates")
#: MDEs a worker keeps in memory (least recently used dropped): a lockstep round uses one per run
WORKER_MDE_CACHE = 64


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask, which ``os.cpu_count`` ignores)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def resolve_workers(value: Any, field: str = "planner.workers") -> int:
    """The number of planner processes for a config value: an integer >= 1, or ``"auto"``.

    ``auto`` = min(CPUs available, :data:`AUTO_MAX_WORKERS`). Anything else is refused with a
    message that names ``field`` and the allowed values (checked before any compute).
    """
    if isinstance(value, str) and value.strip().lower() == "auto":
        return max(1, min(available_cpus(), AUTO_MAX_WORKERS))
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) < 1:
        raise ValueError(
            f"{field} = {value!r}: allowed an integer >= 1 (1 = plan in the main process) or 'auto' "
            f"(= min(CPUs, {AUTO_MAX_WORKERS}) = {max(1, min(available_cpus(), AUTO_MAX_WORKERS))} "
            f"here)"
        )
    return int(value)


@dataclass(frozen=True, eq=False)
class PlanRequest:
    """One planner call: ``kind="plan"`` -> :meth:`Planner.plan` (a :class:`PlanResult`),
    ``kind="candidates"`` -> :meth:`Planner.plan_candidates` with ``n`` (a :class:`CandidateSet`).
    ``None`` means the config's value, as in the :class:`Planner` methods."""

    kind: str
    start: Any
    goal: float
    beta: float | None = None
    d_max: float | None = None
    seed: int | np.random.SeedSequence | None = None
    n: int | None = None
    tol: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise ValueError(f"PlanRequest.kind = {self.kind!r}: allowed one of {_KINDS}")
        if self.kind == "plan" and self.n is not None:
            raise ValueError("PlanRequest.n is for kind='candidates' only")
        object.__setattr__(self, "start", np.array(self.start, dtype=float))

    def run(self, planner: Planner) -> PlanResult | CandidateSet:
        """Execute this request with ``planner`` (the single place both paths call the planner)."""
        if self.kind == "plan":
            return planner.plan(self.start, self.goal, beta=self.beta, d_max=self.d_max, tol=self.tol, seed=self.seed)
        return planner.plan_candidates(
            self.start, self.goal, n=self.n, beta=self.beta, d_max=self.d_max, tol=self.tol, seed=self.seed
        )

    def units(self, config: PlannerConfig) -> list["PlanRequest"]:
        """Single plans whose results make this request's: itself, or the N runs of a candidate set
        with the seeds :meth:`Planner.plan_candidates` gives them (so that they balance over workers)."""
        if self.kind == "plan":
            return [self]
        return [
            PlanRequest("plan", self.start, self.goal, beta=self.beta, d_max=self.d_max, seed=child, tol=self.tol)
            for child in candidate_seeds(config, self.n, self.seed)
        ]


class PlanPool:
    """Run batches of independent :class:`PlanRequest` for one dynamics model and planner config.

    Use as a context manager (or call :meth:`close`)::

        with PlanPool(dynamics, config, workers=2) as pool:
            results = pool.run([PlanRequest("plan", s, g, seed=k) for k, (s, g) in ...], mde)

    ``workers``: an integer (0 or 1 = in-process) or ``"auto"`` (:func:`resolve_workers`).
    ``preload``: modules each worker imports at start-up, e.g. the MDE's (``"mde"`` imports BoTorch
    and GPyTorch, ~1.5 s); otherwise the first batch that carries an MDE pays for that import.
    """

    def __init__(
        self, dynamics: DynamicsModel, config: PlannerConfig, workers: int | str = 1, preload: Sequence[str] = ()
    ) -> None:
        self.dynamics = dynamics
        self.config = config
        self.preload = tuple(preload)
        in_process = isinstance(workers, (int, np.integer)) and not isinstance(workers, bool) and workers in (0, 1)
        self.workers = 1 if in_process else resolve_workers(workers, "workers")
        self.startup_s: float | None = None  # seconds the worker processes took to become ready
        #: why planning went back in-process (None while the workers serve, or with workers <= 1)
        self.fallback_reason: str | None = None
        self._executor: ProcessPoolExecutor | None = None
        self._tmp: Path | None = None
        self._mde_files: dict[str, str] = {}  # token -> path of each MDE the workers may read
        self._closed = False

    # -- public API ---------------------------------------------------------------------------------
    @property
    def parallel(self) -> bool:
        """True when requests go to worker processes (now or on the next :meth:`run`)."""
        return self.workers > 1 and self.fallback_reason is None and not self._closed

    def run(
        self, requests: Sequence[PlanRequest], mde: DeviationEstimator | None = None, errors: str = "raise"
    ) -> list[PlanResult | CandidateSet]:
        """Results of ``requests`` in request order, as in-process calls with ``mde`` would give.

        ``errors``: "raise" (the first failing request's exception ends the batch) or "record" (a
        run that raises becomes a run that found nothing, :func:`failed_run`; the others are unchanged).
        """
        return self.run_groups([(requests, mde)], errors)[0]

    def run_groups(
        self, groups: Sequence[tuple[Sequence[PlanRequest], DeviationEstimator | None]], errors: str = "raise"
    ) -> list[list[PlanResult | CandidateSet]]:
        """:meth:`run` for several (requests, mde) groups at once, spread over the workers together:
        ``out[g][k]`` is what ``run(groups[g][0], groups[g][1])[k]`` gives. How runs that each have
        their own MDE (every method and seed of a lockstep round) share one planning batch."""
        if errors not in _ERRORS:
            raise ValueError(f"PlanPool.run errors = {errors!r}: allowed one of {_ERRORS}")
        if self._closed:
            raise RuntimeError("PlanPool.run after close()")
        groups = [(list(reqs), mde) for reqs, mde in groups]
        for reqs, _ in groups:
            for r in reqs:
                if not isinstance(r, PlanRequest):
                    raise TypeError(f"PlanPool.run takes PlanRequest items, got {type(r).__name__}")
        if not any(reqs for reqs, _ in groups):
            return [[] for _ in groups]
        if self.parallel:
            self.start()
        record = errors == "record"
        if self._executor is None:
            out = [self._run_here(reqs, mde, record) for reqs, mde in groups]
        else:
            out = self._run_in_workers(groups, record)
        _warn_time_budget(out, self.config)
        return out

    def start(self) -> float:
        """Start the worker processes now (otherwise the first :meth:`run` does); returns seconds.

        Separate so that callers can report start-up (spawn + imports + model transfer) apart from
        planning. With ``workers <= 1``, or after a fallback, it does nothing and returns 0.
        """
        if not self.parallel or self._executor is not None:
            return self.startup_s or 0.0
        t0 = time.perf_counter()
        try:
            payload = dumps(self.dynamics)
            pickle.loads(payload)  # fail here, with the reason, rather than in every worker's initializer
            self._tmp = Path(tempfile.mkdtemp(prefix="planpool-"))
            ctx = multiprocessing.get_context("spawn")
            with _thread_env():  # inherited by the children at spawn time
                self._executor = ProcessPoolExecutor(
                    self.workers,
                    mp_context=ctx,
                    initializer=_init_worker,
                    initargs=(payload, self.config, self.preload),
                )
                ready = self._executor.submit(_worker_pid)  # spawns the first process
                for _ in range(self.workers - 1):  # each submit spawns one more (none is idle yet)
                    self._executor.submit(_worker_pid)
            _wait_ready(self._executor, self.workers, ready)
        except Exception as e:  # noqa: BLE001 - any failure to start means: plan in-process
            self._fall_back(f"the planner worker processes could not start ({type(e).__name__}: {e})")
            return 0.0
        self.startup_s = time.perf_counter() - t0
        log.info("planner: %d worker processes ready in %.1f s", self.workers, self.startup_s)
        return self.startup_s

    def close(self, wait_for_workers: bool = True) -> None:
        """Stop the workers and remove the temporary MDE files; later :meth:`run` calls fail.

        ``wait_for_workers=False`` (used when an exception, e.g. Ctrl-C, leaves the ``with``
        block) terminates running workers instead of letting their current plan finish.
        """
        self._closed = True
        self._shutdown(wait_for_workers)

    def __enter__(self) -> "PlanPool":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(wait_for_workers=exc_type is None)

    def __repr__(self) -> str:
        state = (
            "closed"
            if self._closed
            else "in-process"
            if not self.parallel
            else ("running" if self._executor is not None else "not started")
        )
        return f"PlanPool(workers={self.workers}, {state})"

    # -- internals ----------------------------------------------------------------------------------
    def _run_here(self, requests: list[PlanRequest], mde: DeviationEstimator | None, record: bool = False) -> list:
        planner = Planner(self.dynamics, mde, self.config)
        if not record:
            return [r.run(planner) for r in requests]
        out: list = []
        for r in requests:
            if r.kind == "plan":
                out.append(_recorded(lambda u=r: u.run(planner), r, self.config))
            else:  # per run, so that one failing run keeps its siblings' candidates
                out.append(
                    collect_candidates(
                        [_recorded(lambda u=u: u.run(planner), u, self.config) for u in r.units(self.config)]
                    )
                )
        return out

    def _run_in_workers(
        self, groups: list[tuple[list[PlanRequest], DeviationEstimator | None]], record: bool = False
    ) -> list[list]:
        assert self._executor is not None
        unit_sets = [[r.units(self.config) for r in reqs] for reqs, _ in groups]
        units = [u for sets in unit_sets for us in sets for u in us]
        mdes = [mde for (reqs, mde), sets in zip(groups, unit_sets) for us in sets for _ in us]
        if len(units) == 1:  # nothing to run side by side
            return [self._run_here(reqs, mde, record) for reqs, mde in groups]
        try:
            refs = self._publish_mdes([mde for _, mde in groups])
        except Exception as e:  # noqa: BLE001 - e.g. an MDE that does not pickle: it still plans in-process
            self._fall_back(f"the MDE could not be sent to the worker processes ({type(e).__name__}: {e})")
            return [self._run_here(reqs, mde, record) for reqs, mde in groups]
        unit_refs = [ref for ref, sets in zip(refs, unit_sets) for us in sets for _ in us]
        try:
            futures = [self._executor.submit(_work, u, ref) for u, ref in zip(units, unit_refs)]
        except BrokenProcessPool as e:
            self._fall_back(f"a planner worker process died ({e})")
            return [self._run_here(reqs, mde, record) for reqs, mde in groups]
        done: list[PlanResult] = []
        try:
            for u, f in zip(units, futures):
                done.append(_recorded(f.result, u, self.config) if record else f.result())
        except BrokenProcessPool as e:
            self._fall_back(f"a planner worker process died ({e})")
            done += self._finish_here(units[len(done) :], futures[len(done) :], mdes[len(done) :], record)
        except Exception:  # a request failed: as in-process, its error ends the batch
            _drop(futures, wait_running=True)
            raise
        except BaseException:  # KeyboardInterrupt and the like: leave at once
            _drop(futures, wait_running=False)
            raise
        out, i = [], 0
        for (reqs, _), sets in zip(groups, unit_sets):
            results = []
            for r, us in zip(reqs, sets):
                runs, i = done[i : i + len(us)], i + len(us)
                results.append(runs[0] if r.kind == "plan" else collect_candidates(runs))
            out.append(results)
        return out

    def _finish_here(
        self, units: list[PlanRequest], futures: list[Future], mdes: list, record: bool = False
    ) -> list[PlanResult]:
        """After a worker died: keep what finished, plan the rest in-process (in order)."""
        out = []
        for u, f, mde in zip(units, futures, mdes):
            if f.done() and not f.cancelled() and f.exception() is None:
                out.append(f.result())
            else:
                planner = Planner(self.dynamics, mde, self.config)
                out.append(
                    _recorded(lambda u=u, planner=planner: u.run(planner), u, self.config) if record else u.run(planner)
                )
        return out

    def _publish_mdes(self, mdes: list[DeviationEstimator | None]) -> list[tuple[str, str] | None]:
        """Write each MDE where workers read it, unless its content is already there; files of MDEs
        this batch does not use are removed (no request of an earlier batch is still running)."""
        refs: list[tuple[str, str] | None] = []
        for mde in mdes:
            if mde is None:
                refs.append(None)
                continue
            data = dumps(mde)
            token = hashlib.sha256(data).hexdigest()[:20]
            if token not in self._mde_files:
                assert self._tmp is not None
                path = self._tmp / f"mde-{token}.pkl"
                part = path.with_suffix(".part")
                part.write_bytes(data)
                os.replace(part, path)  # a worker never sees half a file
                self._mde_files[token] = str(path)
            refs.append((token, self._mde_files[token]))
        used = {ref[0] for ref in refs if ref is not None}
        for token in [t for t in self._mde_files if t not in used]:
            Path(self._mde_files.pop(token)).unlink(missing_ok=True)
        return refs

    def _fall_back(self, reason: str) -> None:
        self.fallback_reason = reason
        log.warning("planner: %s; planning in the main process from now on (results are the same, only slower)", reason)
        self._shutdown(wait_for_workers=False)

    def _shutdown(self, wait_for_workers: bool) -> None:
        ex, self._executor = self._executor, None
        if ex is not None:
            procs = list((getattr(ex, "_processes", None) or {}).values())
            ex.shutdown(wait=wait_for_workers, cancel_futures=True)
            if not wait_for_workers:
                for p in procs:  # a running plan would otherwise finish first (up to its time budget)
                    with contextlib.suppress(Exception):
                        if p.is_alive():
                            p.terminate()
                for p in procs:
                    with contextlib.suppress(Exception):
                        p.join(timeout=5)
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None
        self._mde_files = {}


_ERRORS = ("raise", "record")


def _warn_time_budget(out: list[list[PlanResult | CandidateSet]], config: PlannerConfig) -> None:
    """Say when runs ended on the wall-clock time budget: those results depend on the machine's speed at
    that moment (a suspended or overloaded process), not only on the seeds, so a rerun may differ."""
    runs = [r for results in out for res in results for r in (getattr(res, "runs", None) or [res])]
    hit = sum(getattr(r.stats, "termination", None) == "time_budget" for r in runs)
    if hit:
        log.warning(
            "planner: %d of %d run(s) stopped on the wall-clock time budget (%g s) before the propagation "
            "budget: not reproducible (was the process suspended or the machine overloaded?)",
            hit,
            len(runs),
            config.time_budget,
        )


def failed_run(request: PlanRequest, error: BaseException, config: PlannerConfig) -> PlanResult:
    """A single run that raised, recorded as a run that found nothing (``termination="error"``), with the
    seed that run reports."""
    seed, _ = run_seeds(run_seed_sequence(config, request.seed))
    stats = PlannerStats.unexpanded("error", seed, float("inf"), tree_size=0, error=f"{type(error).__name__}: {error}")
    return PlanResult(None, stats)


def _recorded(call: Callable[[], PlanResult], unit: PlanRequest, config: PlannerConfig) -> PlanResult:
    """``call()``, or the failure recorded (:func:`failed_run`) when it raises an ``Exception``."""
    try:
        return call()
    except BrokenProcessPool:
        raise
    except Exception as e:  # noqa: BLE001 - recorded, logged, the batch goes on
        log.warning(
            "a plan failed and is recorded as not found (goal %.3f, seed %s): %s: %s",
            unit.goal,
            unit.seed,
            type(e).__name__,
            e,
        )
        return failed_run(unit, e, config)


def _drop(futures: list[Future], wait_running: bool) -> None:
    for f in futures:
        f.cancel()
    if wait_running:
        wait(futures)


@contextlib.contextmanager
def _thread_env() -> Iterator[None]:
    """One thread per library in processes spawned inside this block (the parent's value is restored)."""
    old = {k: os.environ.get(k) for k in _THREAD_ENV}
    os.environ.update({k: "1" for k in _THREAD_ENV})
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _wait_ready(executor: ProcessPoolExecutor, n: int, first: Future, timeout: float = 300.0) -> None:
    """Return once ``n`` distinct workers have answered (each has imported and received the model)."""
    pids = {first.result(timeout=timeout)}
    deadline = time.monotonic() + timeout
    while len(pids) < n and time.monotonic() < deadline:
        pending = [executor.submit(_worker_pid) for _ in range(n)]
        pids.update(f.result(timeout=timeout) for f in pending)
        if len(pids) < n:
            time.sleep(0.05)


# -- pickling -----------------------------------------------------------------------------------------
def dumps(obj: Any) -> bytes:
    """Pickle ``obj`` for a planner worker; ``pickle.loads`` reads it."""
    return pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)


# -- worker side --------------------------------------------------------------------------------------
_WORKER: dict[str, Any] = {}


def _init_worker(dynamics_payload: bytes, config: PlannerConfig, preload: tuple[str, ...] = ()) -> None:
    """Once per worker process: exit with the parent, single-threaded libraries, no SIGINT, the model."""
    _exit_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    os.environ.update({k: "1" for k in _THREAD_ENV})
    torch.set_num_threads(int(config.torch_threads or 1))
    with contextlib.suppress(RuntimeError):  # only possible before any inter-op work
        torch.set_num_interop_threads(1)
    for name in preload:
        importlib.import_module(name)
    _WORKER.update(dynamics=pickle.loads(dynamics_payload), config=config, mdes=OrderedDict())


def _exit_with_parent() -> None:
    """End this worker as soon as the parent process dies (e.g. SIGKILL).

    Without this an orphaned worker waits for work forever: it holds the write end of its own
    task queue, so it never sees end-of-file there.
    """
    parent = multiprocessing.parent_process()
    if parent is None:  # pragma: no cover - always set for spawned children
        return

    def watch() -> None:
        parent.join()  # returns when the parent's sentinel pipe closes, i.e. the parent has exited
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def _worker_pid() -> int:
    return os.getpid()


def _work(request: PlanRequest, mde_ref: tuple[str, str] | None) -> PlanResult | CandidateSet:
    mde = None
    if mde_ref is not None:
        token, path = mde_ref
        cache = _WORKER["mdes"]
        if token not in cache:
            cache[token] = pickle.loads(Path(path).read_bytes())
            while len(cache) > WORKER_MDE_CACHE:
                cache.popitem(last=False)
        cache.move_to_end(token)
        mde = cache[token]
    return request.run(Planner(_WORKER["dynamics"], mde, _WORKER["config"]))
