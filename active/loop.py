"""The active-learning experiment: collect trajectories with a method, refit the MDE, test.

Per method and seed (design section 4): each iteration samples training problems, plans N candidate
trajectories per problem with the current MDE precondition (beta from the schedule), lets the method
choose one, executes the chosen trajectories in the target world (batched, M at a time), labels each
transition with d(f_hat(s, a), s'), refits the MDE after every M trajectories, and then tests: the
same test problems for every method, planned with beta_test, executed, success = plan found and goal
reached. Everything a run needs to continue is written atomically after every iteration; a killed
run started again with the same output directory resumes from the last completed iteration and, on
the CPU with the same seed, ends with the same results (all randomness is derived from
(seed, purpose, iteration, index), never from history).

An iteration is written as a generator (:meth:`MethodRun.iteration_steps`) that yields what it
waits for, planner calls (:class:`PlanNeed`) and simulations (:class:`SimNeed`), so that one run
can be served alone (:meth:`MethodRun.run`) or batched with every other run of a round
(:mod:`active.lockstep`) with the same results.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import json
import logging
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generator, Mapping, Sequence

import numpy as np
import torch
from tqdm.auto import tqdm

from planner import ActionSampler, PlannerConfig, features
from planner.pool import PlanPool, PlanRequest, resolve_workers
from sim.execute import PouringExecutor
from sim.skills import pour
from sim.world import WorldConfig
from task import FEATURE_NAMES, state_distance
from task.problems import Problem, sample_problems

from .experiment import ExperimentConfig
from .io import as_json, load_torch, save_torch, write_csv
from .methods import Choice, RandomPlan, build_method
from .tracking import Tracker

log = logging.getLogger(__name__)

RESULT_FIELDS = ["method", "seed", "iteration", "n_trajectories", "n_transitions", "beta", "test_success",
                 "test_plan_found", "train_goal_reached", "fallbacks", "plan_errors", "plan_seconds", "sim_seconds", "fit_seconds",
                 "test_seconds", "iteration_seconds"]
CATEGORY_FIELDS = ["method", "seed", "iteration", "trajectory", "category", "source", "n_candidates", "steps",
                   "stuck", "stuck_on", "final_spill", "goal", "goal_reached"]
CALIBRATION_FIELDS = ["method", "seed", "iteration", "n", "coverage50", "coverage80", "coverage95", "nll",
                      "coverage95_raw", "nll_raw"]
#: one row per test problem and iteration (``tests.csv``): what became of each problem, not only the rates
OUTCOME_FIELDS = ["problem", "goal", "found", "goal_reached", "category", "final_spill"]
TEST_FIELDS = ["method", "seed", "iteration", *OUTCOME_FIELDS]
#: result columns that are wall-clock times (excluded when comparing a resumed run with a fresh one)
TIMING_FIELDS = {"plan_seconds", "sim_seconds", "fit_seconds", "test_seconds", "iteration_seconds"}
NOOP = np.array([pour(0.0, 0.0)])  # padding trajectory: keeps the number of batch sizes (compiled solvers) small


def derive_seed(*keys: Any) -> int:
    """A 32-bit seed from (seed, purpose, iteration, index...): independent of run history."""
    ints = [k if isinstance(k, int) else zlib.crc32(str(k).encode()) for k in keys]
    return int(np.random.SeedSequence(ints).generate_state(1)[0])


def comparable_config(cfg: Mapping[str, Any]) -> dict:
    """The part of a config that determines results: not run length, logging, progress bars, nor
    where the dynamics cache lives (moving the cache must not make a finished run unresumable)."""
    c = as_json(cfg)
    changed = _changed_method_specs(c)
    c.pop("methods", None)
    if changed:
        c["methods"] = changed
    for k in ("iterations", "methods"):
        c.get("experiment", {}).pop(k, None)
    for k in ("cache_root", "progress"):
        c.get("dynamics", {}).pop(k, None)
    for k in ("wandb", "progress", "method", "runner", "seeds"):  # runner, seeds: how runs are carried out
        c.pop(k, None)
    c.get("planner", {}).pop("workers", None)  # where plans are computed, not what they are
    if isinstance(c.get("acquisition"), dict):
        c["acquisition"] = legacy_acquisition(c["acquisition"])
    for group, neutral in (("experiment", NEUTRAL_EXPERIMENT_SETTINGS), ("mde", NEUTRAL_MDE_SETTINGS)):
        node = c.get(group)
        for k, off in neutral.items():  # a setting added later, at its "off" value
            if isinstance(node, dict) and k in node and node[k] == off:
                node.pop(k)
    return c


def legacy_acquisition(acq: Mapping[str, Any]) -> dict:
    """The acquisition spec as digests saw it before ``configs/acquisition/`` (the same acquisition,
    the same digest, so runs written then still resume): no ``_partial_`` (every spec is one), and
    the paper's alpha with ``form`` eq1 (DiscountedMaxUCB) or lcb (DiscountedMaxLCB)."""
    a = dict(acq)
    a.pop("_partial_", None)
    if a.get("_target_") == "active.acquisition.DiscountedMaxLCB":
        a["_target_"], a["form"] = "active.acquisition.DiscountedMaxUCB", "lcb"
    elif a.get("_target_") == "active.acquisition.DiscountedMaxUCB":
        a.setdefault("form", "eq1")
    return a


#: the method specs from before the registry was part of a run's config (``methods:``): a run whose methods
#: have these specs keeps the digest it had then; any other spec of a method it runs enters the digest
LEGACY_METHOD_SPECS = {
    "random_actions": {"_target_": "active.methods.RandomActions"},
    "random_plan": {"_target_": "active.methods.RandomPlan"},
    "active_cautious": {"_target_": "active.methods.ActiveChoice", "acquisition": {"c": -0.1}},
    "active_mean": {"_target_": "active.methods.ActiveChoice", "acquisition": {"c": 0.0}},
    "active_balanced": {"_target_": "active.methods.ActiveChoice", "acquisition": {"c": 0.1}},
}


def _changed_method_specs(c: Mapping[str, Any]) -> dict:
    """The specs, among the methods the run executes, that differ from :data:`LEGACY_METHOD_SPECS`."""
    specs = c.get("methods")
    if not isinstance(specs, dict):
        return {}
    method = c.get("method", "all")
    used = list(c.get("experiment", {}).get("methods", [])) if method == "all" else [method]
    return {m: specs[m] for m in used if m in specs and specs[m] != LEGACY_METHOD_SPECS.get(m)}


#: experiment keys added after runs existed, with the value that changes nothing: left out of the digest
#: so that a directory written before the key existed still resumes
NEUTRAL_EXPERIMENT_SETTINGS = {"plan_goal_tol": None, "plan_spill_limit": None, "plan_accept_tol": None,
                               "fallback": "random_actions"}
#: the same for the MDE's keys
NEUTRAL_MDE_SETTINGS = {"lengthscale_max": None, "latent_std_min": None, "latent_std_max": None, "label_max": None,
                        "noise_lengthscale_max": None, "hyperparameter_priors": "none"}


def config_digest(cfg: Mapping[str, Any]) -> str:
    """Hash of everything that determines results (:func:`comparable_config`)."""
    return hashlib.sha256(json.dumps(comparable_config(cfg), sort_keys=True).encode()).hexdigest()[:16]


@dataclass
class Context:
    """What every method of one run shares: models, simulator, problems, held-out data."""

    cfg: dict
    exp: ExperimentConfig
    world: WorldConfig
    planner_cfg: PlannerConfig
    dynamics: Any
    executor: PouringExecutor
    test_problems: list[Problem]
    calibration: dict  # X, y tensors of held-out target-world transitions
    out: Path
    seed: int
    progress: bool = True
    timings: dict = field(default_factory=dict)
    #: state digests this run may resume besides its own (legacy digests; see active.rundir.accepted_digests)
    accepted_digests: frozenset = frozenset()
    #: runs the planner calls (planner.workers processes; shared by all methods); None: in-process
    pool: PlanPool | None = None

    def planner_pool(self) -> PlanPool:
        if self.pool is None:
            self.pool = PlanPool(self.dynamics, self.planner_cfg, workers=1)
        return self.pool


#: planner keys the world or the experiment fixes: ``configs/planner/default.yaml`` interpolates them from
#: their source, and a run whose planner value differs from the source's (set on the planner side) is refused
DERIVED_PLANNER_KEYS = {
    "move_x": "world.skills.move.x", "move_y": "world.skills.move.y", "pour_theta": "world.skills.pour.theta",
    "pour_hold": "world.skills.pour.hold", "max_actions": "world.skills.max_actions",
    "spill_limit": "world.problems.max_spill", "d_max": "experiment.d_max", "n_candidates": "experiment.candidates",
    "time_budget": "experiment.planner_time_budget",
    "propagation_budget": "experiment.planner_propagation_budget",
}
#: PlannerConfig fields that are no settings of a run, and where their values come from instead
NOT_RUN_SETTINGS = {
    "beta": "experiment.beta_train / experiment.beta_test (passed with every planning call)",
    "seed": "the run's seed (every planning call derives its own)",
    "goal_tol": "experiment.plan_goal_tol (null: world.problems.tolerance)",
    "accept_tol": "experiment.plan_accept_tol (null: no fallback band)",
    "move_lattice": "world.skills.lattice (absent: 0, continuous move targets)",
}


def planning_dynamics(dynamics_cfg: Mapping[str, Any], world_cfg: Mapping[str, Any], world: WorldConfig,
                      exp: ExperimentConfig, progress: bool = False) -> Any:
    """The model the experiment plans with: the cached source-world dynamics model of ``dynamics_cfg``
    (trained on first use), wrapped with the known static geometry when ``experiment.known_obstacles``."""
    import dynamics  # heavy (torch models): imported where a model is needed

    dyn = dynamics.load_or_train(dynamics_cfg, world_cfg=world_cfg, progress=progress)
    return dynamics.ContactAwareDynamics(dyn, world) if exp.known_obstacles else dyn


def build_planner_config(world: WorldConfig, planner: Mapping[str, Any], exp: ExperimentConfig) -> PlannerConfig:
    """The run's :class:`PlannerConfig` from the ``planner:`` block, checked against world and experiment.

    The keys of :data:`DERIVED_PLANNER_KEYS` must equal their source (the YAML interpolates them; an
    absent one is taken from the source); the goal band is ``experiment.plan_goal_tol`` or the world's
    tolerance, its fallback band ``experiment.plan_accept_tol``, the spill limit ``experiment.plan_spill_limit`` or
    the world's ``max_spill``. Unknown keys and :data:`NOT_RUN_SETTINGS` are refused, naming the allowed keys.
    ``planner.workers`` is validated here but is not a :class:`PlannerConfig` field (it says where plans
    are computed, not what they are): see :func:`planner_workers`.
    """
    d = dict(planner)
    d.pop("_target_", None)
    planner_workers(d)
    d.pop("workers", None)
    allowed = sorted(({f.name for f in dataclasses.fields(PlannerConfig)} - set(NOT_RUN_SETTINGS)) | {"workers"})
    unknown = sorted(set(d) - set(allowed) - set(NOT_RUN_SETTINGS))
    if unknown:
        raise ValueError(f"unknown planner key(s) {['planner.' + k for k in unknown]}; allowed: {allowed}")
    fixed = sorted(set(d) & set(NOT_RUN_SETTINGS))
    if fixed:
        raise ValueError("; ".join(f"planner.{k} is not a setting of a run: its value is {NOT_RUN_SETTINGS[k]}"
                                   for k in fixed))
    for k, src in DERIVED_PLANNER_KEYS.items():
        want = _source_value(src, world, exp)
        if k not in d:
            d[k] = want
        elif _plain(d[k]) != _plain(want):
            raise ValueError(f"planner.{k} = {d[k]!r} differs from {src} = {want!r}: the planner's value is "
                             f"{src}'s (configs/planner/default.yaml interpolates it); set {src} instead")
    d["goal_tol"] = _planner_bound(world, exp, "plan_goal_tol", "tolerance", "(")
    d["spill_limit"] = _planner_bound(world, exp, "plan_spill_limit", "max_spill", "[")
    if exp.plan_accept_tol is not None:
        d["accept_tol"] = _planner_bound(world, exp, "plan_accept_tol", "tolerance", "(")
        if d["accept_tol"] < d["goal_tol"]:
            raise ValueError(f"experiment.plan_accept_tol = {exp.plan_accept_tol}: allowed [{d['goal_tol']}, "
                             f"{world.problems['tolerance']}] (from the planner's goal band to the world's tolerance)")
    d["move_lattice"] = float(world.skills.get("lattice", 0.0))
    return PlannerConfig.from_dict(d)


def _source_value(path: str, world: WorldConfig, exp: ExperimentConfig) -> Any:
    head, *rest = path.split(".")
    if head == "experiment":
        return getattr(exp, rest[0])
    cur: Any = getattr(world, rest[0])
    for k in rest[1:]:
        cur = cur[k]
    return cur


def _plain(v: Any) -> Any:
    """Numbers as floats, sequences as tuples: ``[0.1, 0.52]`` (YAML) equals ``(0.1, 0.52)``."""
    if isinstance(v, (list, tuple)):
        return tuple(_plain(x) for x in v)
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return float(v)
    return v


def planner_workers(planner: Mapping[str, Any]) -> int:
    """Planner processes from ``planner.workers`` (an integer >= 1 or ``auto``; absent: ``auto``)."""
    return resolve_workers(planner.get("workers", "auto"), "planner.workers")


def _planner_bound(world: WorldConfig, exp: ExperimentConfig, exp_key: str, world_key: str, lower: str) -> float:
    """The planner's value of a bound the world sets (goal band, spill limit): ``world.problems[world_key]``, or
    the experiment's narrower ``exp_key``; success is always judged with the world's value. ``lower`` is the
    allowed range's opening bracket, for the error message."""
    limit = float(world.problems[world_key])
    value = getattr(exp, exp_key)
    if value is None:
        return limit
    if value > limit:
        raise ValueError(f"experiment.{exp_key} = {value}: allowed {lower}0, {limit}] "
                         f"(world.problems.{world_key}; success is always judged with the world's value)")
    return float(value)


def label_transitions(dynamics: Any, s: np.ndarray, a: np.ndarray, s_next: np.ndarray,
                      weights: Mapping[str, float]) -> np.ndarray:
    """MDE labels d(f_hat(s, a), s')."""
    with torch.no_grad():
        pred = dynamics.predict(torch.as_tensor(s, dtype=torch.float32), torch.as_tensor(a, dtype=torch.float32))
    return state_distance(pred.double().numpy(), s_next, weights)


@dataclass
class PlanNeed:
    """Planner calls a run waits for, all with one MDE (None: the model alone)."""

    requests: list[PlanRequest]
    mde: Any


@dataclass
class SimNeed:
    """Trajectories a run waits for, executed in the target world; ``batch``: the most a run's need of this
    kind holds (a training chunk, the test problems). Trajectory k samples its water as slot k."""

    problems: list[Problem]
    actions: list[np.ndarray]
    batch: int


def execute_needs(executor: PouringExecutor, needs: list[SimNeed]) -> list[list]:
    """Every need's trajectories in one target-world simulation; ``out[i]`` are ``needs[i]``'s results.

    Each trajectory keeps the particle-sampling slot it has when its run executes alone, and the
    environments of a batch do not interact, so a run's results do not depend on what else is in the
    batch (bit for bit on the CPU). The batch is padded with do-nothing trajectories to the next power
    of two, at most the sum of the needs' ``batch``: few sizes, so few compiled solvers, and few pads
    (a round of 20 runs whose 30 test problems gave 10 plans simulates 16 environments, not 600).
    """
    probs = [p for n in needs for p in n.problems]
    if not probs:
        return [[] for _ in needs]
    for n in needs:
        if len(n.problems) != len(n.actions) or len(n.problems) > n.batch:
            raise ValueError(f"SimNeed: {len(n.problems)} problems, {len(n.actions)} action sequences, batch {n.batch}")
    actions = [a for n in needs for a in n.actions]
    slots = [k for n in needs for k in range(len(n.problems))]
    size = min(sum(n.batch for n in needs), 1 << (len(probs) - 1).bit_length())
    pad = size - len(probs)
    slots += range(len(probs), size)  # the pads' own slots (unused by any trajectory)
    starts = np.array([p.start[:3] for p in probs] + [probs[0].start[:3]] * pad)
    jit = np.array([p.plant_jitter for p in probs] + [probs[0].plant_jitter] * pad)
    goals = [p.goal for p in probs] + [probs[0].goal] * pad
    res = executor.run("target", starts, actions + [NOOP] * pad, plant_jitter=jit, goals=goals, slots=slots)
    out, i = [], 0
    for n in needs:
        out.append(res[i:i + len(n.problems)])
        i += len(n.problems)
    return out


def problem_outcomes(problems: Sequence[Problem], executed: Mapping[int, Any]) -> list[dict]:
    """One row per test problem (:data:`OUTCOME_FIELDS`): ``executed`` maps the index of each problem whose
    plan was found to its execution result; the others are rows with ``found`` False and no category."""
    rows = []
    for k, p in enumerate(problems):
        r = executed.get(k)
        rows.append({"problem": k, "goal": round(float(p.goal), 4), "found": r is not None,
                     "goal_reached": bool(r is not None and r.goal_reached),
                     "category": r.category if r is not None else "",
                     "final_spill": round(float(r.final_spill), 4) if r is not None else ""})
    return rows


def serve_alone(ctx: Context, need: PlanNeed | SimNeed) -> list:
    """What a run waiting for ``need`` gets when it runs by itself."""
    if isinstance(need, PlanNeed):
        return ctx.planner_pool().run(need.requests, need.mde, errors="record")
    return execute_needs(ctx.executor, [need])[0]


def make_calibration_set(world: WorldConfig, dynamics: Any, executor: PouringExecutor, sampler: ActionSampler,
                         n: int, length: int, seed: int) -> dict:
    """Held-out target-world transitions from random actions (the same for every method of a seed)."""
    problems = sample_problems(world, n, derive_seed(seed, "calibration"), world="target")
    rng = np.random.default_rng(derive_seed(seed, "calibration-actions"))
    acts = [sampler.sample(length, rng) for _ in problems]
    res = executor.run("target", np.array([p.start[:3] for p in problems]), acts,
                       plant_jitter=np.array([p.plant_jitter for p in problems]))
    s, a, s2 = _stack_steps(res)
    y = label_transitions(dynamics, s, a, s2, world.distance_weights)
    return {"X": torch.as_tensor(features(s, a)), "y": torch.as_tensor(y)}


def _stack_steps(results: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    steps = [st for r in results if not r.unstable for st in r.steps]
    if not steps:
        return np.zeros((0, 5)), np.zeros((0, 3)), np.zeros((0, 5))
    return (np.stack([st.s for st in steps]), np.stack([st.a for st in steps]), np.stack([st.s_next for st in steps]))


class MethodRun:
    """One method of one seed: its dataset, MDE, results; resumable from ``<out>/<method>/state.pt``."""

    def __init__(self, ctx: Context, method: str, make_mde, make_acquisition, tracker: Tracker):
        self.ctx, self.method = ctx, method
        self.spec = build_method(method, ctx.cfg.get("methods"))  # the run's methods: node
        self.dir = ctx.out / method
        self.dir.mkdir(parents=True, exist_ok=True)
        self.make_mde, self.make_acq, self.tracker = make_mde, make_acquisition, tracker
        self.sampler = ActionSampler(ctx.planner_cfg)
        self.state = {"completed": 0, "digest": config_digest(ctx.cfg), "X": torch.zeros(0, 8, dtype=torch.float64),
                      "y": torch.zeros(0, dtype=torch.float64), "results": [], "categories": [], "calibration": [],
                      "tests": [], "n_trajectories": 0, "mde_path": None}
        self.mde = make_mde()
        state_path = self.dir / "state.pt"
        if state_path.exists():
            self._resume(state_path)

    # ------------------------------------------------------------------ persistence
    def _resume(self, path: Path) -> None:
        from .rundir import load_mde_checkpoint, state_fix

        st = load_torch(path, fix=state_fix(path))
        if st.get("digest") != self.state["digest"] and st.get("digest") not in self.ctx.accepted_digests:
            raise RuntimeError(f"{path} was written by a run with a different configuration; use a new output "
                               f"directory (hydra.run.dir=...) or delete {self.dir} to restart this method")
        st["digest"] = self.state["digest"]  # an accepted legacy digest: saved as the current one from now on
        st.setdefault("tests", [])  # state of a run made before tests.csv existed: its rows start here
        st["calibration"] = [legacy_calibration_row(r) for r in st["calibration"]]
        self.state = st
        if st["mde_path"]:
            self.mde = load_mde_checkpoint(type(self.mde), self.dir / st["mde_path"], self.mde, st["X"], path)
        log.info("%s: resuming after iteration %d", self.method, st["completed"])

    def _save(self, iteration: int) -> None:
        mde_name = None
        if getattr(self.mde, "is_fitted", False):
            mde_name = f"mde_iter{iteration:03d}.pt"
            self.mde.save(self.dir / mde_name)
        self.state["mde_path"] = mde_name
        self.state["completed"] = iteration
        save_torch(self.dir / "dataset.pt", {"X": self.state["X"], "y": self.state["y"],
                                             "feature_names": list(FEATURE_NAMES)})
        fields = RESULT_FIELDS + (["test_success_refined"] if self.ctx.exp.refine_steps else [])
        write_csv(self.dir / "results.csv", self.state["results"], fields)
        write_csv(self.dir / "categories.csv", self.state["categories"], CATEGORY_FIELDS)
        write_csv(self.dir / "calibration.csv", self.state["calibration"], CALIBRATION_FIELDS)
        write_csv(self.dir / "tests.csv", self.state["tests"], TEST_FIELDS)
        save_torch(self.dir / "state.pt", self.state)  # last: it marks the iteration as complete

    # ------------------------------------------------------------------ the loop
    @property
    def completed(self) -> int:
        """Iterations finished (and saved)."""
        return int(self.state["completed"])

    def run(self) -> list[dict]:
        ctx, exp = self.ctx, self.ctx.exp
        its = range(self.completed, exp.iterations)
        bar = tqdm(its, disable=not ctx.progress, desc=f"{self.method} seed {ctx.seed}", unit="it",
                   initial=self.completed, total=exp.iterations)
        for it in bar:
            ctx.planner_pool().start()  # worker start-up (first iteration of a run only) is not planning time
            steps = self.iteration_steps(it)
            need = next(steps)
            while True:
                try:
                    need = steps.send(serve_alone(ctx, need))
                except StopIteration as done:
                    row = done.value
                    break
            self.finish_iteration(it, row)
        return self.state["results"]

    def finish_iteration(self, it: int, row: dict) -> None:
        """Save iteration ``it`` (atomically; it is complete from here on), print its line, log it."""
        self._save(it + 1)
        line = (f"[{self.method} seed {self.ctx.seed}] iteration {it + 1}/{self.ctx.exp.iterations}: "
                f"{row['n_trajectories']} trajectories, {row['n_transitions']} transitions, "
                f"test success {row['test_success']:.2f}, plans found {row['test_plan_found']:.2f}, "
                f"{row['iteration_seconds']:.0f} s")
        tqdm.write(line)  # above the bars (printed with or without them)
        self.tracker.log({k: v for k, v in row.items() if isinstance(v, (int, float))}, step=it + 1)

    def iteration_steps(self, it: int) -> Generator[PlanNeed | SimNeed, list, dict]:
        """Iteration ``it`` as a generator: it yields what it waits for (planner calls, simulations),
        receives their results, and returns the iteration's row of ``results.csv``. Who serves the
        needs, alone (:meth:`run`) or batched with other runs (:func:`active.lockstep.run_lockstep`),
        changes no result: every need's result is determined by the need itself.

        Times are the wall time of the calls the run waited for: in lockstep, calls shared by all
        runs of the round.
        """
        ctx, exp = self.ctx, self.ctx.exp
        t_start = time.perf_counter()
        beta = exp.beta(it)
        problems = sample_problems(ctx.world, exp.trajectories_per_iteration, derive_seed(ctx.seed, "train", it),
                                   world="target")
        plan_mde = self.mde if self.mde.is_fitted else None  # the precondition the planner uses
        t_plan = t_sim = t_fit = 0.0
        fallbacks = reached = 0
        self.plan_errors = 0  # planner runs that raised this iteration (recorded as not found)
        for c0 in range(0, len(problems), exp.refit_every):
            chunk = problems[c0:c0 + exp.refit_every]
            tp = time.perf_counter()
            cand_sets = yield from self._plan_chunk(chunk, plan_mde, it, c0, beta)  # one planning batch per chunk
            reference = _candidate_steps(cand_sets)
            choices = [self._choose(prob, cands, it, c0 + j, reference)
                       for j, (prob, cands) in enumerate(zip(chunk, cand_sets))]
            choices = yield from self._plan_fallbacks(chunk, choices, it, c0)
            t_plan += time.perf_counter() - tp
            ts = time.perf_counter()
            results = yield SimNeed(chunk, [c.actions for c in choices], exp.refit_every)
            t_sim += time.perf_counter() - ts
            for j, (prob, ch, r) in enumerate(zip(chunk, choices, results)):
                fallbacks += ch.source.startswith("fallback")  # no admitted candidate (either fallback)
                reached += bool(r.goal_reached)
                self.state["categories"].append({
                    "method": self.method, "seed": ctx.seed, "iteration": it + 1, "trajectory": self.state["n_trajectories"],
                    "category": r.category, "source": ch.source, "n_candidates": ch.n_candidates, "steps": len(r.steps),
                    "stuck": r.stuck, "stuck_on": r.stuck_on or "", "final_spill": round(r.final_spill, 4),
                    "goal": round(prob.goal, 4),
                    "goal_reached": r.goal_reached})
                self.state["n_trajectories"] += 1
            s, a, s2 = _stack_steps(results)
            if len(s):
                y = label_transitions(ctx.dynamics, s, a, s2, ctx.world.distance_weights)
                self.state["X"] = torch.cat([self.state["X"], torch.as_tensor(features(s, a))])
                self.state["y"] = torch.cat([self.state["y"], torch.as_tensor(y)])
            tf = time.perf_counter()
            if len(self.state["y"]):
                self.mde.fit(self.state["X"], self.state["y"])  # a failed fit keeps the previous one
                plan_mde = self.mde
            t_fit += time.perf_counter() - tf
        tt = time.perf_counter()
        success, found = yield from self._test(plan_mde, it)
        t_test = time.perf_counter() - tt
        self._calibrate(it)
        row = {"method": self.method, "seed": ctx.seed, "iteration": it + 1,
               "n_trajectories": self.state["n_trajectories"], "n_transitions": int(len(self.state["y"])), "beta": beta,
               "test_success": success, "test_plan_found": found,
               **({"test_success_refined": self.last_refined_success} if exp.refine_steps else {}), "train_goal_reached": reached / len(problems),
               "fallbacks": fallbacks, "plan_errors": self.plan_errors, "plan_seconds": round(t_plan, 3), "sim_seconds": round(t_sim, 3),
               "fit_seconds": round(t_fit, 3), "test_seconds": round(t_test, 3),
               "iteration_seconds": round(time.perf_counter() - t_start, 3)}
        self.state["results"].append(row)
        return row

    def _plan_chunk(self, chunk: list[Problem], mde: Any, it: int, c0: int, beta: float):
        """Candidate sets of the chunk's problems (problem k = c0 + j), planned in one batch."""
        ctx, exp = self.ctx, self.ctx.exp
        if not self.spec.plans:  # e.g. random_actions
            return [None] * len(chunk)
        reqs = [PlanRequest("candidates", prob.start, prob.goal, n=exp.candidates, beta=beta, d_max=exp.d_max,
                            seed=derive_seed(ctx.seed, self.method, "plan", it, c0 + j))
                for j, prob in enumerate(chunk)]
        sets = yield PlanNeed(reqs, mde if self.spec.plans_with_mde else None)
        self.plan_errors += sum(r.stats.termination == "error" for s in sets for r in s.runs)
        return sets

    def _plan_fallbacks(self, chunk: list[Problem], choices: list[Choice], it: int, c0: int):
        """``experiment.fallback = model_plan``: each problem whose candidates the MDE all refused gets a plan of
        the model alone (no MDE), planned in one batch; where that finds nothing too, the random actions stay."""
        ctx, exp = self.ctx, self.ctx.exp
        idx = [j for j, c in enumerate(choices) if c.source == "fallback"]
        if exp.fallback != "model_plan" or not idx:
            return choices
        reqs = [PlanRequest("plan", chunk[j].start, chunk[j].goal, d_max=exp.d_max,
                            seed=derive_seed(ctx.seed, self.method, "fallback-plan", it, c0 + j)) for j in idx]
        found = yield PlanNeed(reqs, None)
        self.plan_errors += sum(res.stats.termination == "error" for res in found)
        choices = list(choices)
        for j, res in zip(idx, found):
            if res.found:
                choices[j] = Choice(np.asarray(res.trajectory.actions), "fallback_plan", 0)
        return choices

    def _choose(self, prob: Problem, cands: Any, it: int, k: int, reference: torch.Tensor | None = None):
        ctx, exp = self.ctx, self.ctx.exp
        rng = np.random.default_rng(derive_seed(ctx.seed, self.method, "choose", it, k))

        def random_actions() -> np.ndarray:
            return self.sampler.sample(exp.random_actions_length, rng)

        if not self.spec.plans:
            return self.spec.choose([], rng, random_actions)
        trajs = list(cands.candidates)
        if self.spec.acquisition is not None and not self.mde.is_fitted:
            # no data yet: every candidate has the same prior score; pick one at random (seeded)
            return RandomPlan().choose(trajs, rng, random_actions)
        return self.spec.choose(trajs, rng, random_actions, lambda kw: self.make_acq(self.mde, kw, reference))

    def _test(self, mde: Any, it: int):
        """Plan the test problems with beta_test, execute the plans found; returns (success, found) rates."""
        ctx, exp = self.ctx, self.ctx.exp
        reqs = [PlanRequest("plan", prob.start, prob.goal, beta=exp.beta_test, d_max=exp.d_max,
                            seed=derive_seed(ctx.seed, "test-plan", it, k)) for k, prob in enumerate(ctx.test_problems)]
        found = yield PlanNeed(reqs, mde)  # a failed plan counts as not found
        self.plan_errors += sum(res.stats.termination == "error" for res in found)
        plans = [res.trajectory if res.found else None for res in found]
        idx = [k for k, p in enumerate(plans) if p is not None]
        success = refined = 0
        executed: dict[int, Any] = {}
        if idx:
            probs = [ctx.test_problems[k] for k in idx]
            results = yield SimNeed(probs, [plans[k].actions for k in idx], len(ctx.test_problems))
            executed = dict(zip(idx, results))
            success = sum(bool(r.goal_reached) for r in results)
            if exp.refine_steps:
                from .refine import refine_plans

                ref = refine_plans(ctx.world, [plans[k] for k in idx], [p.goal for p in probs], steps=exp.refine_steps,
                                   lr=exp.refine_lr, progress=ctx.progress)
                results = yield SimNeed(probs, list(ref.actions), len(ctx.test_problems))
                refined = sum(bool(r.goal_reached) for r in results)
        n = len(ctx.test_problems)
        self.state["tests"] += [{"method": self.method, "seed": ctx.seed, "iteration": it + 1, **row}
                                for row in problem_outcomes(ctx.test_problems, executed)]
        self.last_refined_success = refined / n if exp.refine_steps else None
        return success / n, len(idx) / n

    def _calibrate(self, it: int) -> None:
        X, y = self.ctx.calibration["X"], self.ctx.calibration["y"]
        if len(y):
            self.state["calibration"].append(calibration_row(self.mde, X, y, self.method, self.ctx.seed, it + 1))


def legacy_calibration_row(row: dict) -> dict:
    """A calibration row written before rows had ``coverage95_raw``: its figures were against the raw labels, so
    they move to the ``_raw`` columns and the as-fitted ones stay empty (``python -m active.recalibrate`` fills
    them from the run's MDE checkpoints)."""
    if "coverage95_raw" in row:
        return row
    return {**row, "coverage50": None, "coverage80": None, "coverage95": None, "nll": None,
            "coverage95_raw": row.get("coverage95"), "nll_raw": row.get("nll")}


def calibration_row(mde: Any, X: Any, y: Any, method: str, seed: int, iteration: int) -> dict:
    """One row of ``calibration.csv``: the MDE's interval coverage and NLL on the held-out transitions, against
    the labels as the MDE fits them (capped at ``mde.label_max``: a raw label above the cap lies outside every
    interval by construction), and the 95 % coverage and NLL against the raw labels beside them."""
    from mde.calibration import fitted_labels, gaussian_calibration

    mean, std = mde.predict(torch.as_tensor(X))  # once, for both comparisons
    rep = gaussian_calibration(mean, std, fitted_labels(mde, y))
    raw = gaussian_calibration(mean, std, torch.as_tensor(y), levels=(0.95,))
    cov = {float(k): float(v) for k, v in rep["coverage"].items()}
    return {"method": method, "seed": seed, "iteration": iteration, "n": int(rep["n"]),
            "coverage50": cov.get(0.5), "coverage80": cov.get(0.8), "coverage95": cov.get(0.95),
            "nll": float(rep["nll"]), "coverage95_raw": float(raw["coverage"]["0.95"]), "nll_raw": float(raw["nll"])}


def _candidate_steps(cand_sets: list) -> torch.Tensor | None:
    """The features of every step of every candidate in a chunk's candidate sets (None when there are none): the
    transitions the planner currently builds plans from, the reference of a look-ahead acquisition."""
    rows = [np.asarray(c.features) for s in cand_sets if s is not None for c in s.candidates]
    return torch.as_tensor(np.concatenate(rows), dtype=torch.float64) if rows else None


def acquisition_factory(acq_cfg: Mapping[str, Any], exp: ExperimentConfig):
    """Build the configured acquisition (``configs/acquisition/``, a ``_partial_`` spec instantiated with
    ``hydra.utils.instantiate``) for an MDE and a method's keyword arguments (``c``; each passed only
    if the class accepts it, as is ``d_max`` = experiment.d_max and ``beta`` = experiment.beta_test unless the
    spec sets them, and ``reference``: the features of the transitions a look-ahead acquisition scores for).

    A method whose ``acquisition:`` names a ``_target_`` brings its own spec (e.g. ``active_straddle``), built
    the same way instead of the configured one, so that one run can compare acquisitions side by side."""
    from hydra.utils import instantiate

    from .acquisition import _check_gamma

    cfg = dict(acq_cfg)
    if "_target_" not in cfg:
        raise ValueError("acquisition._target_ is missing: e.g. active.acquisition.DiscountedMaxUCB")
    if "form" in cfg:
        raise ValueError(f"acquisition.form = {cfg['form']!r} was removed: the paper's Eq. 1 is acquisition=alpha "
                         f"(the default), its LCB reading acquisition=lcb (active.acquisition.DiscountedMaxLCB)")
    cls = acquisition_class(cfg["_target_"], "acquisition")
    if "gamma" in cfg:
        _check_gamma(cfg["gamma"])
    cfg["_partial_"] = True  # a spec without it (a config written before the group existed) is still a partial
    partial = instantiate(cfg, _convert_="all")
    params = inspect.signature(cls.__init__).parameters

    own: dict[str, Any] = {}  # a method's own spec (its acquisition: names a _target_) -> its factory

    def make(mde: Any, method_kwargs: Mapping[str, Any] | None = None, reference: Any = None):
        method_kwargs = dict(method_kwargs or {})
        if "_target_" in method_kwargs:
            key = json.dumps(method_kwargs, sort_keys=True, default=str)
            if key not in own:
                own[key] = acquisition_factory(method_kwargs, exp)
            return own[key](mde, None, reference)
        kw = {k: v for k, v in method_kwargs.items() if k in params}
        if "d_max" in params and "d_max" not in partial.keywords:
            kw["d_max"] = exp.d_max
        if "beta" in params and "beta" not in partial.keywords and "beta" not in kw:
            kw["beta"] = exp.beta_test  # a look-ahead acquisition's precondition is the test planner's
        if "reference" in params and reference is not None:
            kw["reference"] = reference
        # an MDE's marginal view reads its fit's own factorisation (GPyTorch's refactorisation can fail on it)
        model = getattr(mde, "marginal_model", None)
        model = getattr(mde, "model", mde) if model is None else model
        return partial(model=model, **kw)

    make.accepts = _keywords(cls) - {"model"}  # type: ignore[attr-defined]
    make.target = cfg["_target_"]  # type: ignore[attr-defined]
    return make


def acquisition_class(target: str, where: str) -> type:
    """The class an acquisition spec's ``_target_`` names, or an error naming ``where`` and the built-in ones."""
    from hydra.utils import get_class

    try:
        return get_class(target)
    except Exception as e:
        from .acquisition import ACQUISITIONS

        raise ValueError(f"{where}._target_ = {target!r} cannot be imported ({e}); built in: "
                         f"{sorted(c.__module__ + '.' + c.__name__ for c in ACQUISITIONS.values())}") from None


def check_method_acquisition(name: str, method: Any, make_acquisition: Any) -> None:
    """Refuse, before compute, a method's acquisition keyword that no acquisition takes (a typo would
    otherwise do nothing). A keyword of another built-in acquisition (the paper's ``c`` with
    ``acquisition=variance``) is allowed: the configured one ignores it, as documented. A method's own spec
    (``acquisition._target_``) must import and take each of its keywords."""
    from .acquisition import ACQUISITIONS

    spec = dict(getattr(method, "acquisition", None) or {})
    if "_target_" in spec:  # the method's own acquisition: its keywords must be its class's
        takes = _keywords(acquisition_class(spec["_target_"], f"methods.{name}.acquisition")) - {"model"}
        unknown = sorted(set(spec) - {"_target_", "_partial_"} - takes)
        if unknown:
            raise ValueError(f"methods.{name}.acquisition: {unknown} is not a parameter of {spec['_target_']}; "
                             f"it takes {sorted(takes)}")
        return
    kwargs = set(spec)
    built_in = set().union(*(_keywords(cls) for cls in ACQUISITIONS.values()))
    unknown = sorted(kwargs - set(make_acquisition.accepts) - built_in)
    if unknown:
        raise ValueError(f"methods.{name}.acquisition: {unknown} is a parameter of no acquisition; "
                         f"{make_acquisition.target} takes {sorted(make_acquisition.accepts)}")


def _keywords(cls: type) -> frozenset[str]:
    """The named parameters of ``cls``'s constructor (not ``self``, ``*args`` or ``**kwargs``)."""
    params = inspect.signature(cls.__init__).parameters.items()
    return frozenset(k for k, p in params if k != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD))
