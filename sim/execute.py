"""Batched execution of action sequences in the source or target world.

One call runs B trajectories (up to 6 actions each, lengths may differ) in one batched simulator:
every environment follows its own precomputed cup schedule (``sim.skills``), and its state is read
when each of its actions (settle included) ends. Returns per step (s_t, a_t, s_t+1) and per
trajectory the outcome (goal reached, final spill, stuck, category), optionally GIF frames.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from tqdm.auto import tqdm

from task import goal_reached, spill

from .engine.mpm import MPMSolver
from .engine.render import snapshot
from .skills import Obstacles, Schedule, cup_boundary, plan_schedule, start_overlap, validate_actions
from .world import CTRL, WorldConfig, check_world

log = logging.getLogger(__name__)

CATEGORIES = ("successful_pour", "unsuccessful_pour", "stuck_in_plant", "other")
SCHEDULE_THREADS = 16  # most threads (or processes) that compute a batch's cup schedules
#: batches at least this large compute their cup schedules in worker processes when more than 2 CPUs are
#: available: the schedule's numpy calls are too small to run long without the GIL, so threads bought about
#: nothing at B = 2048 on a 16-core GPU box (BENCHMARKS.md, executing trajectories)
SCHEDULE_PROCESS_MIN_BATCH = 256
SCHEDULE_PROCESS_MIN_CPUS = 3
POUR_EVIDENCE = 0.02  # fraction of water that must leave the controlled cup to call it a pour


@dataclass
class Step:
    s: np.ndarray
    a: np.ndarray
    s_next: np.ndarray
    stuck: bool = False


@dataclass
class TrajectoryResult:
    states: np.ndarray  # (T + 1, 5) observed states
    actions: np.ndarray  # (T, 3) executed actions
    steps: list[Step]
    requested_actions: int
    goal: float | None
    goal_reached: bool | None
    final_spill: float
    stuck: bool
    stuck_on: str | None
    category: str
    unstable: bool
    frames: list[dict] | None = field(default=None, repr=False)


def categorise(states: np.ndarray, stuck_on: str | None, unstable: bool, max_spill: float) -> str:
    """Trajectory type of the paper's Fig. 4 analysis."""
    if stuck_on == "plant":
        return "stuck_in_plant"
    if unstable:
        return "other"
    poured = states[0, 3] - states[:, 3].min() > POUR_EVIDENCE
    if spill(states[-1]) > max_spill and poured:
        return "unsuccessful_pour"
    if poured and states[-1, 4] - states[0, 4] > POUR_EVIDENCE:
        return "successful_pour"
    return "other"


def scene_obstacles(cfg: WorldConfig, bodies: Sequence) -> Obstacles:
    """A scene's bodies other than the controlled cup (``spec.bodies[1:]``), inside the tank's interior."""
    lo, hi = np.full(2, cfg.floor), np.asarray(cfg.sim["domain"], float) - cfg.floor
    return Obstacles(list(bodies), lo, hi)


def schedule_trajectory(
    cfg: WorldConfig, boundary: np.ndarray, bodies: Sequence, start: np.ndarray, actions: np.ndarray, b: int
) -> Schedule:
    """The cup schedule of environment ``b`` (its start pose checked against the obstacles first)."""
    obst = scene_obstacles(cfg, bodies)
    name = start_overlap(obst, boundary, start)
    if name is not None:
        raise ValueError(
            f"starts[{b}] = {np.asarray(start).tolist()}: the cup overlaps the {name} there; "
            f"choose a start pose clear of every obstacle"
        )
    return plan_schedule(cfg, start, actions, obst, boundary)


_WORKER: dict = {}  # the world config and cup outline of a schedule worker process


def _init_schedule_worker(cfg: WorldConfig, boundary: np.ndarray) -> None:
    _WORKER.update(cfg=cfg, boundary=boundary)


def _schedule_in_worker(job: tuple) -> Schedule:
    return schedule_trajectory(_WORKER["cfg"], _WORKER["boundary"], *job)


class PouringExecutor:
    """Runs batches of trajectories; keeps one compiled solver per batch size for reuse."""

    def __init__(self, cfg: WorldConfig, arch: str | None = None):
        self.cfg = cfg
        self.arch = arch
        self._solvers: dict[int, MPMSolver] = {}
        self._boundary = cup_boundary(cfg)
        self.last_timing: dict[str, float] = {}
        self._schedule_pool: ProcessPoolExecutor | None = None  # started by the first large batch

    def solver(self, n_envs: int) -> MPMSolver:
        if n_envs not in self._solvers:
            extra = {"arch": self.arch} if self.arch else {}
            self._solvers[n_envs] = MPMSolver(self.cfg.sim_config(n_envs, **extra))
        return self._solvers[n_envs]

    def close(self) -> None:
        for s in self._solvers.values():
            s.close()
        self._solvers.clear()
        if self._schedule_pool is not None:
            self._schedule_pool.shutdown(cancel_futures=True)
            self._schedule_pool = None

    def _schedules(self, specs: list, starts: np.ndarray, acts: list[np.ndarray]) -> list[Schedule]:
        """Every environment's cup schedule, in order (the first bad start raises first): in worker
        processes for large batches where there are CPUs for them, else on threads (numpy releases
        the GIL in its array loops). The same schedules either way (tests/test_worlds.py). Spawned
        workers import the caller's main module, as planner workers do: a script that runs large batches
        guards its entry point with ``if __name__ == "__main__"`` (else the pool breaks and threads take over)."""
        B = len(specs)
        cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        jobs = [(specs[b].bodies[1:], starts[b], acts[b], b) for b in range(B)]
        if B >= SCHEDULE_PROCESS_MIN_BATCH and cpus >= SCHEDULE_PROCESS_MIN_CPUS:
            workers = min(SCHEDULE_THREADS, cpus)
            if self._schedule_pool is None:
                self._schedule_pool = ProcessPoolExecutor(
                    workers,
                    mp_context=multiprocessing.get_context("spawn"),
                    initializer=_init_schedule_worker,
                    initargs=(self.cfg, self._boundary),
                )
            try:
                return list(self._schedule_pool.map(_schedule_in_worker, jobs, chunksize=max(1, B // (4 * workers))))
            except BrokenProcessPool as e:  # a worker died: the batch goes on in this process
                log.warning("schedule workers failed (%s): computing this batch's schedules on threads", e)
                self._schedule_pool = None
        workers = min(SCHEDULE_THREADS, cpus, max(1, B // 4))
        one = lambda job: schedule_trajectory(self.cfg, self._boundary, *job)  # noqa: E731
        if workers > 1:
            with ThreadPoolExecutor(workers) as pool:
                return list(pool.map(one, jobs))
        return [one(job) for job in jobs]

    def start_obstacles(
        self, world: str, starts: np.ndarray, plant_jitter: np.ndarray | None = None
    ) -> list[str | None]:
        """Per start pose (x, y[, theta]): the obstacle the cup would overlap there (what :meth:`run` refuses),
        or None where it is clear. For callers that build start grids, such as benchmarks."""
        check_world(world)
        starts = np.asarray(starts, float).reshape(len(starts), -1)
        if starts.shape[1] == 2:
            starts = np.concatenate([starts, np.zeros((len(starts), 1))], 1)
        jit = np.zeros((len(starts), 3)) if plant_jitter is None else np.asarray(plant_jitter, float).reshape(-1, 3)
        return [
            start_overlap(self._obstacles(self.cfg.scene(world, p, j)), self._boundary, p) for p, j in zip(starts, jit)
        ]

    def _obstacles(self, spec) -> Obstacles:
        """The scene's bodies other than the controlled cup, inside the tank's interior."""
        return scene_obstacles(self.cfg, spec.bodies[1:])

    def run(
        self,
        world: str,
        starts: np.ndarray,
        actions: Sequence[Sequence[Sequence[float]]],
        plant_jitter: np.ndarray | None = None,
        goals: Sequence[float] | None = None,
        frame_every: float | None = None,
        progress: bool = False,
        freeze_done: bool = True,
        slots: Sequence[int] | None = None,
    ) -> list[TrajectoryResult]:
        """Execute ``actions[b]`` from cup pose ``starts[b]`` (x, y[, theta]) in every environment b.

        ``slots[b]``: the particle-sampling slot of environment b (default b; :meth:`MPMSolver.reset`):
        a trajectory run with the same slot in any batch gives the same result (on the CPU, bit for bit).

        ``freeze_done``: an environment whose trajectory has ended (its last settle observed; stuck
        early, shorter sequence, padding) is frozen and costs nothing for the rest of the batch. The
        running environments' results are the same either way (bit-identical on the CPU); False
        simulates every environment to the end of the longest trajectory (the old behaviour, kept
        for the benchmark's comparison).

        ``world.plant.on_contact: stuck``: a trajectory the plant stopped gets one more step per action
        it had left, attempted without effect (the cup stays caught, s' = s): the deviation a planner's
        model makes by expecting those actions to work is then in the data (under "stop" it is not).
        """
        check_world(world)
        t_all = time.perf_counter()
        starts, goals, acts, specs = self._inputs(world, starts, actions, plant_jitter, goals)
        # --- kinematic schedules with contact (numpy, before any simulation; a GPU batch of thousands
        #     would otherwise wait on one core)
        t0 = time.perf_counter()
        scheds = self._schedules(specs, starts, acts)
        timing = {"schedule": time.perf_counter() - t0}
        solver = self.solver(len(acts))
        solver.reset(specs, slots)
        rollout = _Rollout(self.cfg, solver, scheds, frame_every)
        rollout.play(f"simulate {len(acts)} x {world}", progress, freeze_done)
        unstable = solver.report_unstable()
        results = [
            trajectory_result(
                self.cfg,
                rollout.obs[b],
                acts[b],
                scheds[b],
                None if goals is None else goals[b],
                bool(unstable[b]),
                rollout.frames[b] if rollout.frames is not None else None,
            )
            for b in range(len(acts))
        ]
        timing.update(
            rollout.timing(freeze_done),
            total=time.perf_counter() - t_all,
            sim_seconds=rollout.K * rollout.h,
            substeps=rollout.K * rollout.n_sub,
        )
        self.last_timing = timing
        return results

    def _inputs(
        self,
        world: str,
        starts: np.ndarray,
        actions: Sequence[Sequence[Sequence[float]]],
        plant_jitter: np.ndarray | None,
        goals: Sequence[float] | None,
    ) -> tuple:
        """``run``'s arguments checked: (starts (B, 3), goals (B,) or None, actions as executed, scenes)."""
        starts = np.asarray(starts, float)
        B = len(actions)
        if starts.ndim != 2 or len(starts) != B or starts.shape[1] not in (2, 3):
            raise ValueError(f"starts: expected ({B}, 2) or ({B}, 3) cup poses, got shape {starts.shape}")
        if starts.shape[1] == 2:
            starts = np.concatenate([starts, np.zeros((B, 1))], 1)
        if goals is not None:
            goals = np.asarray(goals, float)
            if goals.shape != (B,) or (goals < 0).any() or (goals > 1).any():
                raise ValueError(f"goals: expected {B} fractions in [0, 1], got {goals}")
        jit = np.zeros((B, 3)) if plant_jitter is None else np.asarray(plant_jitter, float).reshape(B, 3)
        acts = validate_actions(self.cfg, actions)
        specs = [self.cfg.scene(world, starts[b], jit[b]) for b in range(B)]
        return starts, goals, acts, specs


class _Rollout:
    """One batch in the solver: every environment's cup schedule played tick by tick, its state observed when each
    of its actions ends (tick 0 too), environments frozen once their trajectory has ended."""

    def __init__(self, cfg: WorldConfig, solver: MPMSolver, scheds: list[Schedule], frame_every: float | None):
        self.solver = solver
        B = len(scheds)
        self.K = max(len(s.poses) for s in scheds) - 1
        poses = np.stack(
            [np.concatenate([s.poses, np.repeat(s.poses[-1:], self.K + 1 - len(s.poses), 0)]) for s in scheds]
        )  # (B, K + 1, 3)
        solver.load_schedule(CTRL, poses)
        self.regions = cfg.volume_regions()
        self.n_part = solver.particle_counts().astype(float)
        self.h = cfg.control_dt
        self.n_sub = int(round(self.h / solver.cfg.dt))
        self.end_ticks = [set(s.action_end) for s in scheds]
        self.last_tick = np.array([len(s.poses) - 1 for s in scheds])
        self.obs: list[list[np.ndarray]] = [[] for _ in range(B)]
        self.frames: list[list[dict]] | None = [[] for _ in range(B)] if frame_every else None
        self.frame_ticks = max(1, int(round(frame_every / self.h))) if frame_every else 0
        self.seconds = {"simulate": 0.0, "control": 0.0, "state_queries": 0.0, "frames": 0.0}

    def observe(self, k: int) -> None:
        """Record (cup pose, fractions of the water in the two cups) of the environments whose action ends at tick k."""
        tq = time.perf_counter()
        bodies, lo, hi = self.regions
        counts = self.solver.count_in_regions(bodies, lo, hi) / self.n_part[:, None]
        cup = self.solver.body_poses(CTRL)
        for b, obs in enumerate(self.obs):
            if k == 0 or k in self.end_ticks[b]:
                obs.append(np.array([cup[b, 0], cup[b, 1], cup[b, 2], counts[b, 0], counts[b, 1]]))
        self.seconds["state_queries"] += time.perf_counter() - tq

    def play(self, label: str, progress: bool, freeze_done: bool) -> None:
        """Run the K ticks (``PouringExecutor.run``'s ``freeze_done``), the cup at rest after the last."""
        solver, B = self.solver, len(self.obs)
        gpu = solver.arch != "cpu"
        running = np.ones(B, bool)
        self.observe(0)
        any_end = set().union(*self.end_ticks)
        ticks = tqdm(range(self.K), desc=label, unit="tick", leave=False) if progress else range(self.K)
        for k in ticks:
            tc = time.perf_counter()
            solver.track_tick(k + 1, self.h)
            ts = time.perf_counter()
            solver.step(self.n_sub)
            if gpu:
                solver.sync()  # kernels run asynchronously: wait, so the time lands in "simulate"
            self.seconds["control"] += ts - tc
            self.seconds["simulate"] += time.perf_counter() - ts
            if k + 1 in any_end:
                self.observe(k + 1)
                if freeze_done and (self.last_tick == k + 1).any():
                    running &= self.last_tick > k + 1
                    solver.set_active(running)
            if self.frames is not None and (k + 1) % self.frame_ticks == 0:
                tf = time.perf_counter()
                for b in range(B):
                    self.frames[b].append(snapshot(solver, b))
                self.seconds["frames"] += time.perf_counter() - tf
        solver.set_body_velocity(CTRL, np.zeros((B, 2)), np.zeros(B))

    def timing(self, freeze_done: bool) -> dict:
        B, K = len(self.obs), self.K
        return {
            "env_ticks_run": int(np.minimum(self.last_tick, K).sum()) if freeze_done else B * K,
            "env_ticks": B * K,
            **self.seconds,
        }


def trajectory_result(
    cfg: WorldConfig,
    observed: list[np.ndarray],
    acts: np.ndarray,
    sched: Schedule,
    goal: float | None,
    unstable: bool,
    frames: list[dict] | None,
) -> TrajectoryResult:
    """One environment's trajectory from its observed states (one per action end, tick 0 first): its steps (under
    ``world.plant.on_contact: stuck``, the actions left after the plant caught the cup as steps without effect),
    goal, spill and category."""
    states = np.stack(observed)
    n_exec = sched.executed
    steps = [Step(states[t], acts[t], states[t + 1], stuck=t in sched.blocked) for t in range(n_exec)]
    if cfg.plant_on_contact == "stuck" and sched.stuck_on == "plant":  # the rest: tried, no effect
        steps += [Step(states[-1], a, states[-1], stuck=True) for a in acts[n_exec:]]
        states = np.concatenate([states, np.repeat(states[-1:], len(acts) - n_exec, 0)])
        n_exec = len(acts)
    max_spill = cfg.problems["max_spill"]
    g = None if goal is None else float(goal)
    reached = (
        None if g is None else bool(goal_reached(states[-1], g, cfg.problems["tolerance"], max_spill) and not unstable)
    )
    return TrajectoryResult(
        states=states,
        actions=acts[:n_exec],
        steps=steps,
        requested_actions=len(acts),
        goal=g,
        goal_reached=reached,
        final_spill=float(spill(states[-1])),
        stuck=sched.stuck,
        stuck_on=sched.stuck_on,
        category=categorise(states, sched.stuck_on, unstable, max_spill),
        unstable=unstable,
        frames=frames,
    )
