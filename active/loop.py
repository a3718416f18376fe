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

import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generator

import numpy as np
import torch
from tqdm.auto import tqdm

from planner import ActionSampler, PlannerConfig, features
from planner.pool import PlanPool, PlanRequest
from sim.execute import PouringExecutor
from sim.world import WorldConfig
from task import FEATURE_NAMES
from task.problems import Problem, sample_problems

from .calibration import CALIBRATION_FIELDS, calibration_row
from .experiment import ExperimentConfig
from .identity import RUN_FORMAT, RUN_FORMAT_VERSION, config_digest
from .io import file_sha256, save_checked, save_torch, write_csv
from .labels import label_transitions, stack_steps
from .methods import Choice, OracleBound, RandomPlan, build_method
from .needs import OUTCOME_FIELDS, PlanNeed, SimNeed, execute_needs, problem_outcomes
from .oracle import best, score_candidates
from .refine import refine_plans
from .rundir import check_checkpoint, load_mde_checkpoint, load_state
from .seeds import derive_seed
from .tracking import Tracker

log = logging.getLogger(__name__)

RESULT_FIELDS = [
    "method",
    "seed",
    "iteration",
    "n_trajectories",
    "n_transitions",
    "beta",
    "test_success",
    "test_plan_found",
    "train_goal_reached",
    "fallbacks",
    "plan_errors",
    "plan_seconds",
    "sim_seconds",
    "fit_seconds",
    "test_seconds",
    "iteration_seconds",
]
CATEGORY_FIELDS = [
    "method",
    "seed",
    "iteration",
    "trajectory",
    "category",
    "source",
    "n_candidates",
    "steps",
    "stuck",
    "stuck_on",
    "final_spill",
    "goal",
    "goal_reached",
]
TEST_FIELDS = ["method", "seed", "iteration", *OUTCOME_FIELDS]
#: result columns that are wall-clock times (excluded when comparing a resumed run with a fresh one)
TIMING_FIELDS = {"plan_seconds", "sim_seconds", "fit_seconds", "test_seconds", "iteration_seconds"}


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
    #: runs the planner calls (planner.workers processes; shared by all methods); None: in-process
    pool: PlanPool | None = None

    def planner_pool(self) -> PlanPool:
        if self.pool is None:
            self.pool = PlanPool(self.dynamics, self.planner_cfg, workers=1)
        return self.pool


def serve_alone(ctx: Context, need: PlanNeed | SimNeed) -> list:
    """What a run waiting for ``need`` gets when it runs by itself."""
    if isinstance(need, PlanNeed):
        return ctx.planner_pool().run(need.requests, need.mde, errors="record")
    return execute_needs(ctx.executor, [need])[0]


class MethodRun:
    """One method of one seed: its dataset, MDE, results; resumable from ``<out>/<method>/state.pt``."""

    def __init__(self, ctx: Context, method: str, make_mde, make_acquisition, tracker: Tracker):
        self.ctx, self.method = ctx, method
        self.spec = build_method(method, ctx.cfg.get("methods"))  # the run's methods: node
        self.dir = ctx.out / method
        self.dir.mkdir(parents=True, exist_ok=True)
        self.make_mde, self.make_acq, self.tracker = make_mde, make_acquisition, tracker
        self.sampler = ActionSampler(ctx.planner_cfg)
        self.state = {
            "format": RUN_FORMAT,
            "version": RUN_FORMAT_VERSION,
            "completed": 0,
            "digest": config_digest(ctx.cfg),
            "X": torch.zeros(0, 8, dtype=torch.float64),
            "y": torch.zeros(0, dtype=torch.float64),
            "results": [],
            "categories": [],
            "calibration": [],
            "tests": [],
            "n_trajectories": 0,
            "mde_path": None,
        }
        self.mde = make_mde()
        state_path = self.dir / "state.pt"
        if state_path.exists():
            self._resume(state_path)

    # ------------------------------------------------------------------ persistence
    def _resume(self, path: Path) -> None:
        st = load_state(path)
        if st["digest"] != self.state["digest"]:
            raise RuntimeError(
                f"{path} was written by a run with a different configuration; use a new output "
                f"directory (hydra.run.dir=...) or delete {self.dir} to restart this method"
            )
        self.state = st
        if st["mde_path"]:
            check_checkpoint(self.dir / st["mde_path"], st.get("mde_sha256"), path)
            self.mde = load_mde_checkpoint(type(self.mde), self.dir / st["mde_path"], self.mde, st["X"], path)
        self._write_derived()  # the CSVs and dataset.pt from the state: a damaged or edited one is restored
        log.info("%s: resuming after iteration %d", self.method, st["completed"])

    def _save(self, iteration: int) -> None:
        mde_name = None
        if getattr(self.mde, "is_fitted", False):
            mde_name = f"mde_iter{iteration:03d}.pt"
            self.mde.save(self.dir / mde_name)
            self.state["mde_sha256"] = file_sha256(self.dir / mde_name)
        self.state["mde_path"] = mde_name
        self.state["completed"] = iteration
        self._write_derived()
        save_checked(self.dir / "state.pt", self.state)  # last: it marks the iteration as complete

    def _write_derived(self) -> None:
        """The files derived from the state (the source of truth): the CSVs and ``dataset.pt``."""
        save_torch(
            self.dir / "dataset.pt", {"X": self.state["X"], "y": self.state["y"], "feature_names": list(FEATURE_NAMES)}
        )
        fields = RESULT_FIELDS + (["test_success_refined"] if self.ctx.exp.refine_steps else [])
        write_csv(self.dir / "results.csv", self.state["results"], fields)
        write_csv(self.dir / "categories.csv", self.state["categories"], CATEGORY_FIELDS)
        write_csv(self.dir / "calibration.csv", self.state["calibration"], CALIBRATION_FIELDS)
        write_csv(self.dir / "tests.csv", self.state["tests"], TEST_FIELDS)

    # ------------------------------------------------------------------ the loop
    @property
    def completed(self) -> int:
        """Iterations finished (and saved)."""
        return int(self.state["completed"])

    def run(self) -> list[dict]:
        ctx, exp = self.ctx, self.ctx.exp
        its = range(self.completed, exp.iterations)
        bar = tqdm(
            its,
            disable=not ctx.progress,
            desc=f"{self.method} seed {ctx.seed}",
            unit="it",
            initial=self.completed,
            total=exp.iterations,
        )
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
        line = (
            f"[{self.method} seed {self.ctx.seed}] iteration {it + 1}/{self.ctx.exp.iterations}: "
            f"{row['n_trajectories']} trajectories, {row['n_transitions']} transitions, "
            f"test success {row['test_success']:.2f}, plans found {row['test_plan_found']:.2f}, "
            f"{row['iteration_seconds']:.0f} s"
        )
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
        problems = sample_problems(
            ctx.world, exp.trajectories_per_iteration, derive_seed(ctx.seed, "train", it), world="target"
        )
        plan_mde = self.mde if self.mde.is_fitted else None  # the precondition the planner uses
        t = {"plan": 0.0, "sim": 0.0, "fit": 0.0}
        fallbacks = reached = 0
        self.plan_errors = 0  # planner runs that raised this iteration (recorded as not found)
        for c0 in range(0, len(problems), exp.refit_every):
            chunk = problems[c0 : c0 + exp.refit_every]
            tp = time.perf_counter()
            cand_sets = yield from self._plan_chunk(chunk, plan_mde, it, c0, beta)  # one planning batch per chunk
            t["plan"] += time.perf_counter() - tp
            pick = self._oracle_chunk if isinstance(self.spec, OracleBound) else self._chosen_chunk
            choices, results = yield from pick(chunk, cand_sets, it, c0, t)
            f, r = self._record(chunk, choices, results, it)
            fallbacks, reached = fallbacks + f, reached + r
            tf = time.perf_counter()
            if len(self.state["y"]):
                self.mde.fit(self.state["X"], self.state["y"])  # a failed fit keeps the previous one
                plan_mde = self.mde
            t["fit"] += time.perf_counter() - tf
        tt = time.perf_counter()
        success, found = yield from self._test(plan_mde, it)
        t_test = time.perf_counter() - tt
        self._calibrate(it)
        row = {
            "method": self.method,
            "seed": ctx.seed,
            "iteration": it + 1,
            "n_trajectories": self.state["n_trajectories"],
            "n_transitions": int(len(self.state["y"])),
            "beta": beta,
            "test_success": success,
            "test_plan_found": found,
            **({"test_success_refined": self.last_refined_success} if exp.refine_steps else {}),
            "train_goal_reached": reached / len(problems),
            "fallbacks": fallbacks,
            "plan_errors": self.plan_errors,
            "plan_seconds": round(t["plan"], 3),
            "sim_seconds": round(t["sim"], 3),
            "fit_seconds": round(t["fit"], 3),
            "test_seconds": round(t_test, 3),
            "iteration_seconds": round(time.perf_counter() - t_start, 3),
        }
        self.state["results"].append(row)
        return row

    def _chosen_chunk(self, chunk: list[Problem], cand_sets: list, it: int, c0: int, t: dict):
        """The method's choice per problem (fallbacks planned in one batch), executed in one batch; adds the times to
        ``t``. Returns (choices, their results)."""
        tp = time.perf_counter()
        reference = _candidate_steps(cand_sets)
        choices = [
            self._choose(prob, cands, it, c0 + j, reference) for j, (prob, cands) in enumerate(zip(chunk, cand_sets))
        ]
        choices = yield from self._plan_fallbacks(chunk, choices, it, c0)
        t["plan"] += time.perf_counter() - tp
        ts = time.perf_counter()
        results = yield SimNeed(chunk, [c.actions for c in choices], self.ctx.exp.refit_every)
        t["sim"] += time.perf_counter() - ts
        return choices, results

    def _record(self, chunk: list[Problem], choices: list[Choice], results: list, it: int) -> tuple[int, int]:
        """The chunk's rows of ``categories.csv`` and its labelled transitions into the state; returns how many
        trajectories fell back and how many reached their goal."""
        for prob, ch, r in zip(chunk, choices, results):
            self.state["categories"].append(
                {
                    "method": self.method,
                    "seed": self.ctx.seed,
                    "iteration": it + 1,
                    "trajectory": self.state["n_trajectories"],
                    "category": r.category,
                    "source": ch.source,
                    "n_candidates": ch.n_candidates,
                    "steps": len(r.steps),
                    "stuck": r.stuck,
                    "stuck_on": r.stuck_on or "",
                    "final_spill": round(r.final_spill, 4),
                    "goal": round(prob.goal, 4),
                    "goal_reached": r.goal_reached,
                }
            )
            self.state["n_trajectories"] += 1
        X, y = self._labelled(results)
        self.state["X"], self.state["y"] = torch.cat([self.state["X"], X]), torch.cat([self.state["y"], y])
        fallbacks = sum(ch.source.startswith("fallback") for ch in choices)  # no admitted candidate (either fallback)
        return fallbacks, sum(bool(r.goal_reached) for r in results)

    def _plan_chunk(self, chunk: list[Problem], mde: Any, it: int, c0: int, beta: float):
        """Candidate sets of the chunk's problems (problem k = c0 + j), planned in one batch."""
        ctx, exp = self.ctx, self.ctx.exp
        if not self.spec.plans:  # e.g. random_actions
            return [None] * len(chunk)
        reqs = [
            PlanRequest(
                "candidates",
                prob.start,
                prob.goal,
                n=exp.candidates,
                beta=beta,
                d_max=exp.d_max,
                seed=derive_seed(ctx.seed, "plan", it, c0 + j),
            )
            for j, prob in enumerate(chunk)
        ]
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
        reqs = [
            PlanRequest(
                "plan",
                chunk[j].start,
                chunk[j].goal,
                d_max=exp.d_max,
                seed=derive_seed(ctx.seed, "fallback-plan", it, c0 + j),
            )
            for j in idx
        ]
        found = yield PlanNeed(reqs, None)
        self.plan_errors += sum(res.stats.termination == "error" for res in found)
        choices = list(choices)
        for j, res in zip(idx, found):
            if res.found:
                choices[j] = Choice(np.asarray(res.trajectory.actions), "fallback_plan", 0)
        return choices

    def _oracle_chunk(self, chunk: list[Problem], cand_sets: list, it: int, c0: int, t: dict):
        """The oracle bound's choices (:mod:`active.oracle`): every candidate of the chunk executed in one batch, each
        sampling its water as the slot of its problem (as the chosen trajectory of any other method does), then per
        problem the candidate whose data score best (:class:`OracleBound`'s ``score``); adds the times to ``t``
        (scoring, with its planning and simulation, as fit time). Returns (choices, their results)."""
        ctx, exp = self.ctx, self.ctx.exp
        t0 = time.perf_counter()
        validation = (yield from self._validation_set()) if self.spec.score == "admission" else None
        rngs = [np.random.default_rng(derive_seed(ctx.seed, "choose", it, c0 + j)) for j in range(len(chunk))]
        options = [
            [
                Choice(np.asarray(t.actions), "plan", len(cands.candidates), chosen=k)
                for k, t in enumerate(cands.candidates)
            ]
            if cands is not None and len(cands.candidates)
            else [Choice(self.sampler.sample(exp.random_actions_length, rng), "fallback", 0)]  # as RandomPlan's
            for cands, rng in zip(cand_sets, rngs)
        ]
        firsts = yield from self._plan_fallbacks(chunk, [o[0] for o in options], it, c0)
        options = [o if o[0].source != "fallback" else [f] for o, f in zip(options, firsts)]
        t["plan"] += time.perf_counter() - t0
        ts = time.perf_counter()
        flat = [(j, ch) for j, opts in enumerate(options) for ch in opts]
        executed = yield SimNeed(
            [chunk[j] for j, _ in flat],
            [ch.actions for _, ch in flat],
            exp.refit_every * max(exp.candidates, 1),
            slots=[j for j, _ in flat],
        )
        t["sim"] += time.perf_counter() - ts
        tf = time.perf_counter()
        X, y = self.state["X"], self.state["y"]
        choices, results, i = [], [], 0
        for j, opts in enumerate(options):
            outcomes, i = executed[i : i + len(opts)], i + len(opts)
            data = [self._labelled([r]) for r in outcomes]
            k = 0
            if len(opts) > 1:
                if validation is not None:
                    scores = score_candidates(self.make_mde, X, y, data, validation, exp.d_max, exp.beta_test)
                else:
                    scores = yield from self._success_scores(X, y, data)
                k = best(scores, rngs[j])
                opts[k].scores = scores
                opts[k].chosen = k
            choices.append(opts[k])
            results.append(outcomes[k])
            X, y = torch.cat([X, data[k][0]]), torch.cat([y, data[k][1]])
        t["fit"] += time.perf_counter() - tf
        return choices, results

    def _success_scores(self, X: torch.Tensor, y: torch.Tensor, data: list):
        """Per candidate (``data[k]``: its labelled transitions), the test planner's success on the oracle's held-out
        problems with an MDE fitted on (X, y) plus the candidate's data: every candidate's plans in one batch each,
        every found plan executed in one batch (validation problem k samples its water as slot k, whoever planned it);
        a fit that fails, or fits nothing, scores -inf."""
        ctx, exp = self.ctx, self.ctx.exp
        n, stream = self.spec.validation_problems, derive_seed(ctx.seed, "oracle-validation-problems")
        probs = sample_problems(ctx.world, n, stream, world="target")
        reqs = requests_at_test(probs, exp, ctx.seed, "oracle-validation-plan")
        plans = []
        for Xc, yc in data:
            mde = self.make_mde()
            mde.fit(torch.cat([X, Xc]), torch.cat([y, yc]))  # a failed fit leaves it unfitted (warned)
            plans.append((yield PlanNeed(reqs, mde)) if mde.is_fitted else None)
        found = [(c, k) for c, f in enumerate(plans) if f is not None for k, r in enumerate(f) if r.found]
        reached = np.zeros(len(data))
        if found:
            results = yield SimNeed(
                [probs[k] for _, k in found],
                [np.asarray(plans[c][k].trajectory.actions) for c, k in found],
                len(data) * len(probs),
                slots=[k for _, k in found],
            )
            for (c, _), r in zip(found, results):
                reached[c] += bool(r.goal_reached)
        return [reached[c] / len(probs) if plans[c] is not None else -math.inf for c in range(len(data))]

    def _labelled(self, results: list) -> tuple[torch.Tensor, torch.Tensor]:
        """Features and deviation labels of the transitions of executed trajectories (empty tensors if none)."""
        s, a, s2 = stack_steps(results)
        if not len(s):
            return torch.zeros(0, len(FEATURE_NAMES), dtype=torch.float64), torch.zeros(0, dtype=torch.float64)
        y = label_transitions(self.ctx.dynamics, s, a, s2, self.ctx.world.distance_weights)
        return torch.as_tensor(features(s, a)), torch.as_tensor(y)

    def _validation_set(self):
        """The oracle's held-out target-world set (:mod:`active.oracle`), made at its first use and kept in the state:
        problems of a stream of their own, the first half planned with the model alone (random actions where no plan
        is found), the second half random actions."""
        if "validation" in self.state:
            return self.state["validation"]
        ctx, exp = self.ctx, self.ctx.exp
        n = self.spec.validation_trajectories
        probs = sample_problems(ctx.world, n, derive_seed(ctx.seed, "oracle-validation"), world="target")
        reqs = [
            PlanRequest("plan", p.start, p.goal, d_max=exp.d_max, seed=derive_seed(ctx.seed, "oracle-validation", k))
            for k, p in enumerate(probs[: n // 2])
        ]
        found = yield PlanNeed(reqs, None)
        rng = np.random.default_rng(derive_seed(ctx.seed, "oracle-validation-actions"))
        acts = [r.trajectory.actions if r.found else self.sampler.sample(exp.random_actions_length, rng) for r in found]
        acts += [self.sampler.sample(exp.random_actions_length, rng) for _ in probs[n // 2 :]]
        X, y = self._labelled((yield SimNeed(probs, [np.asarray(a) for a in acts], n)))
        self.state["validation"] = {"X": X, "y": y, "plans_found": sum(r.found for r in found)}
        log.info("oracle seed %d: validation set of %d trajectories, %d transitions", ctx.seed, n, len(y))
        return self.state["validation"]

    def _choose(self, prob: Problem, cands: Any, it: int, k: int, reference: torch.Tensor | None = None):
        ctx, exp = self.ctx, self.ctx.exp
        # common random numbers: the stream is the same for every method, so methods differ only by their choice
        rng = np.random.default_rng(derive_seed(ctx.seed, "choose", it, k))

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
        reqs = requests_at_test(ctx.test_problems, exp, ctx.seed, "test-plan", it)
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
                ref = refine_plans(
                    ctx.world,
                    [plans[k] for k in idx],
                    [p.goal for p in probs],
                    steps=exp.refine_steps,
                    lr=exp.refine_lr,
                    progress=ctx.progress,
                )
                results = yield SimNeed(probs, list(ref.actions), len(ctx.test_problems))
                refined = sum(bool(r.goal_reached) for r in results)
        n = len(ctx.test_problems)
        self.state["tests"] += [
            {"method": self.method, "seed": ctx.seed, "iteration": it + 1, **row}
            for row in problem_outcomes(ctx.test_problems, executed)
        ]
        self.last_refined_success = refined / n if exp.refine_steps else None
        return success / n, len(idx) / n

    def _calibrate(self, it: int) -> None:
        X, y = self.ctx.calibration["X"], self.ctx.calibration["y"]
        if len(y):
            self.state["calibration"].append(calibration_row(self.mde, X, y, self.method, self.ctx.seed, it + 1))


def requests_at_test(problems: list[Problem], exp: ExperimentConfig, seed: int, *key: Any) -> list[PlanRequest]:
    """One plan per problem under the test precondition (``beta_test``, ``d_max``), problem k seeded by
    (seed, *key, k): the test problems of a round, the oracle's validation problems."""
    return [
        PlanRequest("plan", p.start, p.goal, beta=exp.beta_test, d_max=exp.d_max, seed=derive_seed(seed, *key, k))
        for k, p in enumerate(problems)
    ]


def _candidate_steps(cand_sets: list) -> torch.Tensor | None:
    """The features of every step of every candidate in a chunk's candidate sets (None when there are none): the
    transitions the planner currently builds plans from, the reference of a look-ahead acquisition."""
    rows = [np.asarray(c.features) for s in cand_sets if s is not None for c in s.candidates]
    return torch.as_tensor(np.concatenate(rows), dtype=torch.float64) if rows else None
