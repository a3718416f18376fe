"""The ladder: can the default world and models show the paper's effect at all?

Four measured rungs, each a precondition of the next, on the default world and the cached default
dynamics model (the same config composition as ``python -m active.run``, overrides accepted):

1. ``reproducibility``: the same partial pour executed in 32 environment slots from one start, from
   32 sampled approach histories, and from 32 pour positions within one grid cell of each other
   (sub-cell offsets: what a model that sees (x, y) cannot tell apart); std of the fraction that ends
   in the target cup. The MDE cannot admit a pour whose outcome scatters more than its precondition
   allows.
2. ``source_model_only``: plans from the learned model alone (no MDE) executed in the *source* world,
   where the model was trained. The paper's story needs a model that is good there.
3. ``target_model_only``: the same in the target world: how much the plant hurts the model.
4. ``ceiling``: an MDE fitted on a large target-world dataset (random plans and random actions), then
   test planning with the paper's precondition (beta_test, d_max) on fresh problems. The best any
   data-collection method can hope for: the top line of the learning curves.

    python -m active.ladder --out outputs/ladder
    python -m active.ladder --out outputs/ladder_stretch +world.sim.stretch_relax=0.02
    python -m active.ladder --out DIR --rungs source_model_only ceiling experiment.plan_goal_tol=0.02
    python -m active.ladder --out DIR --rungs source_model_only target_model_only --model-seeds 0 1 2
    python -m active.ladder --out DIR --rungs ceiling --ceiling-data data/ceiling_sets/stuck_seed0.npz \
        --ceiling-trajectories 64 -- experiment.planner_propagation_budget=30000   # a saved set, or part of it
    python -m active.ladder --out DIR --rungs ceiling --ceiling-seeds 0 1 2      # three training sets: mean, range

Writes ``DIR/ladder.json`` (atomically, after each rung, so a killed run keeps the rungs it finished)
and prints a table with the issue's targets next to the measured figures.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import time
from pathlib import Path
from typing import Any, Sequence

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch and Taichi start their thread pools (active.run)

import numpy as np  # noqa: E402
import torch  # noqa: E402
from hydra.utils import instantiate  # noqa: E402

import safeio  # noqa: E402
from mde.calibration import cross_validate  # noqa: E402
from planner import ActionSampler, features  # noqa: E402
from planner.pool import PlanPool, PlanRequest  # noqa: E402
from sim.engine.config import NUMERICS_REVISION  # noqa: E402
from sim.execute import CATEGORIES, PouringExecutor  # noqa: E402
from sim.problems import sample_problems  # noqa: E402
from sim.skills import MOVE, POUR, move, pour  # noqa: E402
from sim.world import WorldConfig  # noqa: E402

from .labels import label_transitions, stack_steps  # noqa: E402
from .planner_setup import planning_dynamics  # noqa: E402
from .run import compose_config  # noqa: E402
from .seeds import derive_seed  # noqa: E402
from .settings import Settings, read_settings  # noqa: E402

log = logging.getLogger(__name__)

#: targets of the measurable-effect issue (the default world on a CPU)
TARGETS = {
    "reproducibility.max_std": ("<=", 0.010),
    "source_model_only.found": (">=", 0.90),
    "source_model_only.success": (">=", 0.80),
    "ceiling.success": (">=", 0.70),
    "ceiling.found": (">=", 0.80),
}
#: reference partial pours: ``move(0.32, 0.20), pour(theta, hold)``, on the steep part of the outcome curve
POUR_XY = (0.32, 0.20)


def subcell_offsets(n: int, dx: float) -> np.ndarray:
    """n pour-position offsets (m) spread over one grid cell: a regular grid of about sqrt(n) x sqrt(n)
    fractions of dx in x and y (8 x 4 for n = 32)."""
    nx = int(np.ceil(np.sqrt(2 * n)))
    ny = int(np.ceil(n / nx))
    ox, oy = np.meshgrid(np.arange(nx) / nx, np.arange(ny) / ny)
    return dx * np.stack([ox.ravel(), oy.ravel()], 1)[:n]


def reproducibility(world, executor, thetas: Sequence[float], hold: float, n: int = 32, seed: int = 7) -> dict:
    """Std of the fraction in the target cup of one pour (a) across n env slots from one start, (b) across n
    sampled approach histories (problem starts; trajectories stuck on the way are dropped), (c) across n
    pour positions within one grid cell (:func:`subcell_offsets`; same start).

    (c) is the scatter a model of (x, y, ...) sees between neighbouring training pours: the walls and the
    pouring lip sit on the grid differently at each offset (BENCHMARKS.md, the measurable-effect ladder)."""
    starts = np.array([p.start[:3] for p in sample_problems(world, n, seed, world="source")])
    offsets = subcell_offsets(n, float(world.sim["dx"]))
    start = np.array([[0.42, 0.20, 0.0]] * n)
    rows = []
    for th in thetas:
        acts = [[move(*POUR_XY), pour(th, hold)]] * n
        same = executor.run("source", start, acts)
        appr = [r for r in executor.run("source", starts, acts) if not r.stuck]
        offs = executor.run(
            "source", start, [[move(POUR_XY[0] + ox, POUR_XY[1] + oy), pour(th, hold)] for ox, oy in offsets]
        )
        a, b, c = (np.array([r.states[-1, 4] for r in res]) for res in (same, appr, offs))
        rows.append(
            {
                "theta": th,
                "hold": hold,
                "slots_mean": float(a.mean()),
                "slots_std": float(a.std()),
                "approaches": len(b),
                "approaches_mean": float(b.mean()),
                "approaches_std": float(b.std()),
                "offsets_mean": float(c.mean()),
                "offsets_std": float(c.std()),
                "slots_spill_mean": float(np.mean([r.final_spill for r in same])),
            }
        )
    return {
        "pours": rows,
        "slots_std": [r["slots_std"] for r in rows],
        "approaches_std": [r["approaches_std"] for r in rows],
        "offsets_std": [r["offsets_std"] for r in rows],
        "max_std": max(max(r["slots_std"], r["approaches_std"], r["offsets_std"]) for r in rows),
    }


def plan_all(pool, mde, problems, exp, seed: int, purpose: str, mde_beta: float | None = None) -> list:
    """One plan per problem (None where none is found), seeded per (seed, purpose, index), on the
    :class:`planner.PlanPool` (``planner.workers`` processes; same plans as in-process)."""
    beta = exp.beta_test if mde_beta is None else mde_beta
    reqs = [
        PlanRequest(
            "plan", prob.start, prob.goal, beta=beta, d_max=exp.d_max, seed=derive_seed(seed, "ladder", purpose, k)
        )
        for k, prob in enumerate(problems)
    ]
    # a plan that raises is logged and recorded as not found; the rung goes on
    return [res.trajectory if res.found else None for res in pool.run(reqs, mde, errors="record")]


def execute_plans(executor, world_name: str, problems, plans) -> list:
    """Execute the found plans in one batch; returns the results in problem order (None where no plan)."""
    idx = [k for k, p in enumerate(plans) if p is not None]
    out: list = [None] * len(plans)
    if not idx:
        return out
    jit = np.array([problems[k].plant_jitter for k in idx])
    if world_name == "source":
        jit[:] = 0.0
    res = executor.run(
        world_name,
        np.array([problems[k].start[:3] for k in idx]),
        [plans[k].actions for k in idx],
        plant_jitter=jit,
        goals=[problems[k].goal for k in idx],
    )
    for k, r in zip(idx, res):
        out[k] = r
    return out


def model_only(world, world_name: str, pool, exp, executor, n: int, seed: int) -> dict:
    """Plans from the model alone (no MDE) for n problems, executed in ``world_name``."""
    problems = sample_problems(world, n, derive_seed(seed, "ladder-problems", world_name), world=world_name)
    return plan_and_execute(world, world_name, pool, None, problems, exp, executor, seed, f"model-only-{world_name}")


def plan_and_execute(world, world_name: str, pool, mde, problems, exp, executor, seed: int, purpose: str) -> dict:
    """One plan per problem (:func:`plan_all`, with ``mde``), the found ones executed in ``world_name``: found and
    success rates, outcomes, planning time and per-problem records."""
    t0 = time.perf_counter()
    plans = plan_all(pool, mde, problems, exp, seed, purpose)
    t_plan = time.perf_counter() - t0
    res = execute_plans(executor, world_name, problems, plans)
    done = [r for r in res if r is not None]
    return {
        "n": len(problems),
        "found": len(done) / len(problems),
        "success": sum(bool(r.goal_reached) for r in done) / len(problems),
        **outcomes(world, done),
        "plan_seconds": t_plan,
        "problems": per_problem(problems, res),
    }


def per_problem(problems, res: list) -> list[dict]:
    """One row per problem: where it started, its goal, and what its plan did (``found`` false: no
    plan). Why: a rung's rate says how many problems fail, these rows say which (goal, start)."""
    rows = []
    for prob, r in zip(problems, res):
        row = {
            "start": [round(float(v), 4) for v in prob.start[:3]],
            "goal": round(float(prob.goal), 4),
            "found": r is not None,
        }
        if r is not None:
            row.update(
                actions=len(r.steps),
                category=r.category,
                goal_reached=bool(r.goal_reached),
                final_target=round(float(r.states[-1, 4]), 4),
                final_spill=round(float(r.final_spill), 4),
            )
        rows.append(row)
    return rows


def outcomes(world, done: list) -> dict:
    """How the executed plans ended: trajectory categories, mean |final target fraction - goal|, and how
    many spilled over the world's limit (what a found-but-failed plan did)."""
    errors = [abs(r.states[-1, 4] - r.goal) for r in done]
    return {
        "categories": {c: sum(r.category == c for r in done) for c in CATEGORIES},
        "mean_abs_goal_error": float(np.mean(errors)) if errors else None,
        "spill_over_limit": sum(r.final_spill > world.problems["max_spill"] for r in done),
    }


#: trajectories per simulated batch of a ceiling set: trajectory i runs in env slot i % CEILING_BATCH
CEILING_BATCH = 32


def ceiling_train_problems(world, n_train: int, seed: int) -> list:
    """The problems (start, plant jitter, goal) of ladder seed ``seed``'s ceiling training set, in order."""
    return sample_problems(world, n_train, derive_seed(seed, "ladder-ceiling-train"), world="target")


def ceiling_dataset(world, pool, exp, executor, n_train: int, seed: int, batch: int = CEILING_BATCH) -> dict:
    """n_train target-world trajectories (half random plans of the model alone, half random action
    sequences), as arrays: s, a, s_next (transitions of stable trajectories), trajectory (each
    transition's trajectory index) and category (one per trajectory)."""
    n_plans = n_train // 2
    train_probs = ceiling_train_problems(world, n_train, seed)
    plans = plan_all(pool, None, train_probs[:n_plans], exp, seed, "ceiling-train")
    sampler = ActionSampler(pool.config)
    rng = np.random.default_rng(derive_seed(seed, "ladder-ceiling-actions"))
    acts = [p.actions if p is not None else sampler.sample(exp.random_actions_length, rng) for p in plans]
    acts += [sampler.sample(exp.random_actions_length, rng) for _ in train_probs[n_plans:]]
    results = []
    for i in range(0, n_train, batch):
        chunk = train_probs[i : i + batch]
        results += executor.run(
            "target",
            np.array([p.start[:3] for p in chunk]),
            acts[i : i + batch],
            plant_jitter=np.array([p.plant_jitter for p in chunk]),
            goals=[p.goal for p in chunk],
        )
    s, a, s2 = stack_steps(results)
    kept = [(i, r) for i, r in enumerate(results) if not r.unstable]  # as _stack_steps
    return {
        "s": s,
        "a": a,
        "s_next": s2,
        "trajectory": np.array([i for i, r in kept for _ in r.steps], dtype=int),
        "category": np.array([r.category for r in results]),
        "train_plans_found": np.array(sum(p is not None for p in plans)),
        "plant_on_contact": np.array(world.plant_on_contact),
        "numerics_revision": np.array(NUMERICS_REVISION),
    }


def check_ceiling_data(path: Path, on_contact: str) -> None:
    """Refuse a saved ceiling set made under another ``world.plant.on_contact``: a set made with ``stop`` lacks
    the stuck records that ``stuck`` adds (s' = s for each action a caught cup never made), so its MDE would
    silently be another one. A set that does not record it is refused too (remake it with this command), and so is a
    set simulated with other arithmetic (``sim.engine.config.NUMERICS_REVISION``): its pours are not this code's."""
    with np.load(path) as f:
        made = str(f["plant_on_contact"]) if "plant_on_contact" in f.files else None
        revision = int(f["numerics_revision"]) if "numerics_revision" in f.files else 1
    if revision != NUMERICS_REVISION:
        raise ValueError(
            f"--ceiling-data {path}: simulated with the solver's numerics revision {revision}, this code's is "
            f"{NUMERICS_REVISION} (sim.engine.config.NUMERICS_REVISION); remake it: python -m active.ladder --out DIR "
            f"--rungs ceiling"
        )
    if made is None:
        raise ValueError(
            f"--ceiling-data {path}: records no world.plant.on_contact (not a ceiling set of this code); "
            f"remake it: python -m active.ladder --out DIR --rungs ceiling"
        )
    if made != on_contact:
        raise ValueError(
            f"--ceiling-data {path}: made with world.plant.on_contact={made}, but the run has "
            f"world.plant.on_contact={on_contact}; pass world.plant.on_contact={made} or use a set made "
            f"with {on_contact}"
        )


def ceiling_subset(data: dict, k: int) -> dict:
    """The first k // 2 random-plan and k - k // 2 random-action trajectories of a saved ceiling dataset
    (:func:`ceiling_dataset`: plans first, then random actions, n // 2 of each), renumbered; for a
    learning curve of the ceiling over data from one simulated set."""
    n = len(data["category"])
    if not 2 <= k <= n:
        raise ValueError(f"--ceiling-trajectories {k} with --ceiling-data: allowed 2..{n} (the file's trajectories)")
    ids = np.r_[np.arange(k // 2), n // 2 + np.arange(k - k // 2)]
    rows = np.isin(data["trajectory"], ids)
    renum = np.searchsorted(ids, data["trajectory"][rows])
    sub = {
        "s": data["s"][rows],
        "a": data["a"][rows],
        "s_next": data["s_next"][rows],
        "trajectory": renum,
        "category": data["category"][ids],
        "train_plans_found": np.array(-1),
    }  # unknown for a subset
    return sub | ({"plant_on_contact": data["plant_on_contact"]} if "plant_on_contact" in data else {})


def ceiling(
    world,
    dyn,
    pool,
    exp,
    executor,
    make_mde,
    n_train: int,
    n: int,
    seed: int,
    data_path: Path | None = None,
    reuse: bool = False,
) -> dict:
    """Fit the MDE on n_train target-world trajectories (:func:`ceiling_dataset`), then plan n fresh
    test problems with the paper's precondition.

    ``data_path`` (``.npz``): the training transitions are written there before the fit, so that
    MDE variants can be studied offline; with ``reuse`` they are read from there instead of being
    simulated again (labels are always recomputed with ``dyn``), all of them or, with ``n_train`` > 0,
    :func:`ceiling_subset` of them."""
    if reuse:
        if data_path is None or not Path(data_path).exists():
            raise FileNotFoundError(f"--ceiling-data {data_path}: no such file")
        with np.load(data_path) as f:
            data = {k: f[k] for k in f.files}
        if n_train:
            data = ceiling_subset(data, n_train)
        n_train = len(data["category"])
    else:
        data = ceiling_dataset(world, pool, exp, executor, n_train, seed)
    s, a = data["s"], data["a"]
    y = label_transitions(dyn, s, a, data["s_next"], world.distance_weights)
    if data_path is not None and not reuse:
        safeio.atomic_write(data_path, lambda f: np.savez(f, **data))
    t0 = time.perf_counter()
    mde = make_mde().fit(torch.as_tensor(features(s, a)), torch.as_tensor(y))
    t_fit = time.perf_counter() - t0
    # why plans are (not) found: how much of the data the test precondition admits, per skill, in
    # sample and held out by trajectory (the second is what new problems meet)
    X = torch.as_tensor(features(s, a))
    mu, sd = (v.double().numpy() for v in mde.predict(X)) if len(y) else (np.zeros(0), np.zeros(0))
    t0 = time.perf_counter()
    cv = (
        cross_validate(make_mde, X, torch.as_tensor(y), torch.as_tensor(data["trajectory"]), folds=5)
        if len(np.unique(data["trajectory"])) >= 5
        else None
    )
    t_cv = time.perf_counter() - t0
    per_skill = {}
    for name, code in (("move", MOVE), ("pour", POUR)):
        m = a[:, 0] == code if len(a) else np.zeros(0, bool)
        if m.any():
            per_skill[name] = {
                "n": int(m.sum()),
                "label_mean": float(np.mean(y[m])),
                "label_std": float(np.std(y[m])),
                "pred_mean": float(np.mean(mu[m])),
                "pred_std_mean": float(np.mean(sd[m])),
                **_admission(mu[m], sd[m], y[m], exp, "in_sample"),
            }
            if cv is not None:
                per_skill[name].update(_admission(cv[0].numpy()[m], cv[1].numpy()[m], y[m], exp, "heldout"))
    return {
        "train_trajectories": n_train,
        "train_plans_found": int(data.get("train_plans_found", -1)),
        "train_transitions": int(len(y)),
        "label_mean": float(np.mean(y)) if len(y) else None,
        "label_below_d_max": float(np.mean(np.asarray(y) < exp.d_max)) if len(y) else None,
        "precondition_on_train": per_skill,
        **ceiling_test(world, pool, mde, exp, executor, n, seed),
        "fit_seconds": t_fit,
        "cv_seconds": t_cv,
    }


def ceiling_test(world, pool, mde, exp, executor, n: int, seed: int) -> dict:
    """Plan ceiling seed ``seed``'s n target-world test problems with ``mde`` under the test precondition and
    execute the plans found: found, success, outcomes, planning time and per-problem records. Any MDE can be put
    on the same problems this way (a run's own, one fitted on pooled data)."""
    test = sample_problems(world, n, derive_seed(seed, "ladder-ceiling-test"), world="target")
    return plan_and_execute(world, "target", pool, mde, test, exp, executor, seed, "ceiling-test")


def _admission(mu: np.ndarray, sd: np.ndarray, y: np.ndarray, exp, prefix: str) -> dict:
    """Share of transitions the test precondition admits: all, those whose true deviation is under
    d_max (good: should be admitted) and those over it (bad: should not)."""
    ok = mu + exp.beta_test * sd < exp.d_max
    good = y < exp.d_max
    frac = lambda m: float(np.mean(ok[m])) if m.any() else None  # noqa: E731
    return {
        f"{prefix}_admitted": float(np.mean(ok)),
        f"{prefix}_admitted_good": frac(good),
        f"{prefix}_admitted_bad": frac(~good),
    }


def run_ladder(
    cfg: dict,
    out: Path,
    rungs: Sequence[str],
    thetas: Sequence[float],
    hold: float,
    n: int,
    n_train: int,
    slots: int = 32,
    progress: bool = True,
    ceiling_data: Path | Sequence[Path] | None = None,
    model_seeds: Sequence[int] | None = None,
    ceiling_seeds: Sequence[int] | None = None,
) -> dict:
    """Measure the requested rungs; ``ladder.json`` is rewritten after each one.

    ``model_seeds``: the model-only rungs are measured with a dynamics model trained with each of these
    seeds (``dynamics.train.seed``; each cached by its config hash) on the same data and problems, and
    report the mean over the models with each model's figures (``per_model_seed``): one training draw
    moves the source rung by up to 0.4 (BENCHMARKS.md, the measurable-effect ladder). The ceiling uses the first model.
    None: the config's model only.

    ``ceiling_seeds``: the ceiling is measured once per seed, each with its own training set and test
    problems (saved to ``DIR/ceiling_train_seed<s>.npz``, or read from the matching ``ceiling_data``
    file), and reports the mean, the range and each set's record (``per_seed``): one training set moves
    the ceiling from 0.00 to 0.60 (BENCHMARKS.md, the measurable-effect ladder). None: the config's seed only."""
    seed = int(cfg.get("seed", 0))
    settings, ceiling_runs = _checked_inputs(cfg, rungs, seed, ceiling_seeds, ceiling_data, out)
    exp, world, planner_cfg, workers = settings.exp, settings.world, settings.planner, settings.workers
    out.mkdir(parents=True, exist_ok=True)
    record = _Record(
        out / "ladder.json",
        {"world": cfg["world"], "dynamics": cfg["dynamics"], "experiment": cfg["experiment"], "seed": seed},
    )
    executor = PouringExecutor(world)
    if "reproducibility" in rungs:
        t0 = time.perf_counter()
        record.save("reproducibility", reproducibility(world, executor, thetas, hold, n=slots), t0)
    seeds = [settings.dynamics.train.seed] if model_seeds is None else [int(k) for k in model_seeds]
    model_rungs = [r for r in ("source_model_only", "target_model_only") if r in rungs]
    per_seed: dict[str, list[dict]] = {r: [] for r in model_rungs}
    mde_cfg = dict(cfg["mde"])
    make_mde = lambda: instantiate(mde_cfg, _convert_="all")  # noqa: E731
    for i, model_seed in enumerate(seeds if set(rungs) & {*model_rungs, "ceiling"} else []):
        if i > 0 and not model_rungs:
            break
        t0 = time.perf_counter()
        dyn_cfg = settings.dynamics.replace(train=dataclasses.replace(settings.dynamics.train, seed=model_seed))
        dyn = planning_dynamics(dyn_cfg, world, exp, progress)
        record.result.setdefault("rung_seconds", {})["dynamics" if i == 0 else f"dynamics_seed{model_seed}"] = (
            time.perf_counter() - t0
        )
        with PlanPool(dyn, planner_cfg, workers, preload=[type(make_mde()).__module__]) as pool:
            for name in model_rungs:
                t0 = time.perf_counter()
                per_seed[name].append(
                    {"model_seed": model_seed, **model_only(world, name.split("_")[0], pool, exp, executor, n, seed)}
                )
                record.save(name, _mean_over(per_seed[name], "model_seed"), t0)
            if "ceiling" in rungs and i == 0:
                t0, rows = time.perf_counter(), []
                for ceiling_seed, data_path, reuse in ceiling_runs:
                    measured = ceiling(
                        world,
                        dyn,
                        pool,
                        exp,
                        executor,
                        make_mde,
                        n_train,
                        n,
                        ceiling_seed,
                        data_path=data_path,
                        reuse=reuse,
                    )
                    rows.append({"seed": ceiling_seed, **measured})
                    record.save("ceiling", _mean_over(rows, "seed"), t0)
    executor.close()
    return record.close()


def _checked_inputs(
    cfg: dict,
    rungs: Sequence[str],
    seed: int,
    ceiling_seeds: Sequence[int] | None,
    ceiling_data: Path | Sequence[Path] | None,
    out: Path,
) -> tuple[Settings, list[tuple[int, Path, bool]]]:
    """The run's settings and its ceiling measurements (:func:`_ceiling_runs`), every input checked before any compute:
    the rungs, the seeds and saved sets (made under this plant model and numerics revision)."""
    unknown = sorted(set(rungs) - set(RUNGS))
    if unknown:
        raise ValueError(f"--rungs {unknown}: allowed any of {list(RUNGS)}")
    ceiling_runs = _ceiling_runs(seed, ceiling_seeds, ceiling_data, out)
    settings = read_settings(cfg, method="all")
    if "ceiling" in rungs:
        for _, data_file, reuse in ceiling_runs:
            if reuse:
                check_ceiling_data(data_file, settings.world.plant_on_contact)
    return settings, ceiling_runs


class _Record:
    """``ladder.json``: the config, each rung's result and its seconds, rewritten (atomically) after each rung."""

    def __init__(self, path: Path, config: dict) -> None:
        self.path, self.t_start = path, time.perf_counter()
        self.result: dict[str, Any] = {"config": config}

    def save(self, name: str, value: Any, t0: float) -> None:
        self.result[name] = value
        self.result.setdefault("rung_seconds", {})[name] = time.perf_counter() - t0
        self.close()
        log.info("ladder: %s done (%.0f s)", name, time.perf_counter() - t0)

    def close(self) -> dict:
        self.result["seconds"] = time.perf_counter() - self.t_start
        safeio.write_json(self.path, self.result, indent=1, default=float)
        return self.result


RUNGS = ("reproducibility", "source_model_only", "target_model_only", "ceiling")


def _ceiling_runs(
    seed: int, ceiling_seeds: Sequence[int] | None, ceiling_data: Path | Sequence[Path] | None, out: Path
) -> list[tuple[int, Path, bool]]:
    """(seed, data file, reuse) of each ceiling measurement; a bad combination raises before any compute."""
    seeds = [seed] if ceiling_seeds is None else [int(s) for s in ceiling_seeds]
    if not seeds or len(set(seeds)) != len(seeds) or min(seeds) < 0:
        raise ValueError(f"--ceiling-seeds {list(seeds)}: allowed distinct integers >= 0")
    if ceiling_data is None:
        name = (lambda s: "ceiling_train.npz") if ceiling_seeds is None else (lambda s: f"ceiling_train_seed{s}.npz")
        return [(s, out / name(s), False) for s in seeds]
    files = [Path(ceiling_data)] if isinstance(ceiling_data, (str, os.PathLike)) else [Path(f) for f in ceiling_data]
    if len(files) != len(seeds):
        raise ValueError(
            f"--ceiling-data has {len(files)} file(s) but --ceiling-seeds {seeds} has {len(seeds)}: "
            "give one seed per file (the seed its set was made with: it also draws the test problems)"
        )
    return [(s, f, True) for s, f in zip(seeds, files)]


def _mean_over(rows: list[dict], key: str) -> dict:
    """A rung measured several times (``key``: ``model_seed``, one dynamics model each; ``seed``, one ceiling
    training set and test set each): the first record with found, success and the mean goal error replaced
    by their means, their ranges, the seeds in ``<key>s`` and each record in ``per_<key>`` (a single
    record: as it is)."""
    if len(rows) == 1:
        return {k: v for k, v in rows[0].items() if k != key}
    out = {k: v for k, v in rows[0].items() if k not in (key, "categories", "problems")}
    for k in ("found", "success", "mean_abs_goal_error"):
        if k not in rows[0]:
            continue
        vals = [r[k] for r in rows if r[k] is not None]
        out[k] = float(np.mean(vals)) if vals else None
        out[f"{k}_range"] = [float(min(vals)), float(max(vals))] if vals else None
    out["plan_seconds"] = float(sum(r["plan_seconds"] for r in rows))
    out[f"{key}s"] = [r[key] for r in rows]
    out[f"per_{key}"] = rows
    return out


def _get(result: dict, dotted: str) -> Any:
    cur: Any = result
    for part in dotted.split("."):
        if not isinstance(cur, dict) or part not in cur:
            return None
        cur = cur[part]
    return cur


def table(result: dict) -> str:
    """The rungs as a table with the targets; a rung not run shows '-'."""
    lines = [f"{'rung':34s} {'measured':>9s} {'target':>9s}  met"]
    rows = [
        ("reproducibility.max_std", "{:.3f}"),
        ("source_model_only.found", "{:.2f}"),
        ("source_model_only.success", "{:.2f}"),
        ("target_model_only.found", "{:.2f}"),
        ("target_model_only.success", "{:.2f}"),
        ("ceiling.found", "{:.2f}"),
        ("ceiling.success", "{:.2f}"),
    ]
    for key, fmt in rows:
        v = _get(result, key)
        op, tgt = TARGETS.get(key, (None, None))
        met = "" if v is None or op is None else ("yes" if (v <= tgt if op == "<=" else v >= tgt) else "NO")
        rng, rung = _get(result, key + "_range"), key.split(".")[0]
        models, sets = _get(result, rung + ".model_seeds"), _get(result, rung + ".seeds")
        what = f"{len(models)} models" if models else f"{len(sets or [])} training sets"
        over = "" if rng is None else f"  (mean of {what}: {fmt.format(rng[0])}-{fmt.format(rng[1])})"
        lines.append(
            f"{key:34s} {'-' if v is None else fmt.format(v):>9s} "
            f"{'' if op is None else f'{op} {tgt:g}':>9s}  {met}{over}"
        )
    for r in _get(result, "reproducibility.pours") or []:
        offs = f", sub-cell offsets {r['offsets_mean']:.3f} +- {r['offsets_std']:.3f}" if "offsets_std" in r else ""
        lines.append(
            f"  pour theta {r['theta']:.2f} hold {r['hold']:.2f}: slots {r['slots_mean']:.3f} +- "
            f"{r['slots_std']:.3f}, approaches {r['approaches_mean']:.3f} +- {r['approaches_std']:.3f}{offs}"
        )
    for skill, r in (_get(result, "ceiling.precondition_on_train") or {}).items():
        f = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
        lines.append(
            f"  ceiling precondition, {skill}s: admits good/bad {f(r.get('in_sample_admitted_good'))}/"
            f"{f(r.get('in_sample_admitted_bad'))} in sample, {f(r.get('heldout_admitted_good'))}/"
            f"{f(r.get('heldout_admitted_bad'))} held out by trajectory"
        )
    if "seconds" in result:
        lines.append(f"wall time {result['seconds']:.0f} s")
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    """The command line of ``python -m active.ladder``."""
    ap = argparse.ArgumentParser(
        prog="python -m active.ladder", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--out", type=Path, required=True, help="output directory (ladder.json)")
    ap.add_argument("--rungs", nargs="+", default=list(RUNGS), help=f"which rungs (default all: {' '.join(RUNGS)})")
    ap.add_argument(
        "--thetas",
        type=float,
        nargs="+",
        default=[1.15, 1.25],
        help="pour angles of the reproducibility rung, on the steep part of the default world's "
        "outcome curve (0.30 and 0.49 of the water)",
    )
    ap.add_argument("--hold", type=float, default=0.5, help="hold time of the reproducibility pours, s")
    ap.add_argument("--slots", type=int, default=32, help="environment slots / approaches per reproducibility pour")
    ap.add_argument("--problems", type=int, default=30, help="problems per planning rung")
    ap.add_argument(
        "--ceiling-trajectories",
        type=int,
        default=None,
        help="target-world training trajectories (default 128; with --ceiling-data: all of the file's, "
        "or this many of them, half random plans and half random actions)",
    )
    ap.add_argument(
        "--ceiling-data",
        type=Path,
        nargs="+",
        default=None,
        help="reuse the training transitions of an earlier run (its DIR/ceiling_train.npz) instead "
        "of simulating them; labels are recomputed with the current dynamics model "
        "(several files: one per --ceiling-seeds entry)",
    )
    ap.add_argument(
        "--ceiling-seeds",
        type=int,
        nargs="+",
        default=None,
        help="measure the ceiling once per seed, each with its own training set and test problems, "
        "and report the mean and range (default: the config's seed only)",
    )
    ap.add_argument(
        "--model-seeds",
        type=int,
        nargs="+",
        default=None,
        help="measure the model-only rungs with a dynamics model trained with each of these seeds "
        "(dynamics.train.seed; trained on first use, cached) and report their mean and range "
        "(default: the config's model only)",
    )
    ap.add_argument("overrides", nargs="*", help="Hydra overrides, as for python -m active.run")
    return ap


def main(argv: Sequence[str] | None = None) -> None:
    ap = _parser()
    args, extra = ap.parse_known_args(argv)
    bad = [e for e in extra if "=" not in e]
    if bad:
        ap.error(f"unrecognized arguments: {' '.join(bad)}")
    # `--rungs a b key=value`: argparse hands the overrides to --rungs; they are overrides
    # (the same for --ceiling-data's files)
    files = [str(f) for f in args.ceiling_data or []]
    args.overrides = [r for r in args.rungs + files if "=" in r] + list(args.overrides) + extra
    args.rungs = [r for r in args.rungs if "=" not in r]
    if args.ceiling_data is not None:
        args.ceiling_data = [Path(f) for f in files if "=" not in f]
    n_ceiling = args.ceiling_trajectories
    if n_ceiling is None:
        args.ceiling_trajectories = 0 if args.ceiling_data is not None else 128  # 0: all of the file's
    elif n_ceiling < 2:
        raise SystemExit(f"--ceiling-trajectories {n_ceiling}: allowed >= 2")
    if args.problems < 1 or args.slots < 2:
        raise SystemExit(f"--problems {args.problems} / --slots {args.slots}: allowed >= 1 / >= 2")
    if args.model_seeds is not None and (
        len(set(args.model_seeds)) != len(args.model_seeds) or min(args.model_seeds) < 0
    ):
        raise SystemExit(f"--model-seeds {args.model_seeds}: allowed distinct integers >= 0")
    for f in args.ceiling_data or []:
        if not f.is_file():
            raise SystemExit(f"--ceiling-data {f}: no such file")
    try:  # a bad seed list or a file count that does not match it: refused before any compute
        _ceiling_runs(0, args.ceiling_seeds, args.ceiling_data, args.out)
    except ValueError as err:
        raise SystemExit(str(err)) from None
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    cfg = compose_config(args.overrides)
    on_contact = WorldConfig.from_mapping(cfg["world"]).plant_on_contact
    for f in args.ceiling_data or []:
        try:
            check_ceiling_data(f, on_contact)
        except ValueError as err:
            raise SystemExit(str(err)) from None
    result = run_ladder(
        cfg,
        args.out,
        args.rungs,
        args.thetas,
        args.hold,
        args.problems,
        args.ceiling_trajectories,
        slots=args.slots,
        progress=bool(cfg.get("progress", True)),
        ceiling_data=args.ceiling_data,
        model_seeds=args.model_seeds,
        ceiling_seeds=args.ceiling_seeds,
    )
    print(table(result))
    print(f"wrote {args.out / 'ladder.json'}")


if __name__ == "__main__":
    main()
