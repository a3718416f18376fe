"""The experiment runner (the README's main job).

    python -m active.run                                    # experiment=quick: active vs random, seed 0
    python -m active.run experiment=paper method=active_balanced seed=2
    python -m active.run -m method=active_cautious,active_balanced,random_plan seed=0,1,2,3
    python -m active.run experiment=paper runner=lockstep seeds=[0,1,2,3]   # one process, batched rounds

Writes, under the run directory (``outputs/<experiment>/<method>/seed<seed>`` by default; running the
same command again resumes it): the resolved config, per method ``results.csv``, ``categories.csv``,
``calibration.csv``, ``tests.csv`` (what became of each test problem), ``dataset.pt``, MDE checkpoints
and ``state.pt``, per seed ``model_only.csv`` (the model alone on the test problems,
:mod:`active.baseline`), and the figures of
``active.report`` in ``report/``. With ``seeds=[...]`` every seed gets such a directory,
``seed<s>/``, and ``report/`` covers them all. ``run.lock`` names the run writing the directory (a second run
into it is refused; a killed one's lock is taken over).
"""

from __future__ import annotations

import logging
import os
import time
import warnings
from pathlib import Path
from typing import Any, Mapping

import configs

# OpenMP threads that spin while waiting stall each other (and the simulator's threads) on small
# machines shared with other jobs; passive waiting costs nothing measurable on an idle machine.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

log = logging.getLogger("active.run")


RUNNERS = ("sequential", "lockstep")


def run_experiment(cfg: Mapping[str, Any], out_dir: str | Path) -> dict:
    """Run (or resume) every method of ``cfg`` into ``out_dir``; returns the report summary.

    ``runner``: ``sequential`` runs the methods one after another; ``lockstep`` advances all of them
    (and all ``seeds``) one iteration at a time, batching each round's planning and simulation
    (:mod:`active.lockstep`; the same results on the CPU). ``seeds``: a list runs every seed in this
    process, each into ``out_dir/seed<s>`` (a directory a single-seed run with ``seed=<s>`` would
    write, and can resume), with a report over all seeds in ``out_dir/report``; null: ``seed`` only,
    into ``out_dir`` itself.

    Order matters: every check runs before any compute (config values, the resolution against the
    geometry, the output and cache locations' writability); then each directory is locked (one
    writer per run directory) and what it holds is checked against its config; ``config.json`` is
    written only once the directory is accepted.
    """
    import contextlib

    import torch
    from hydra.utils import instantiate

    from planner import ActionSampler
    from planner.pool import PlanPool
    from sim.execute import PouringExecutor
    from task.problems import sample_problems

    from . import baseline
    from .io import write_json
    from .lockstep import run_lockstep
    from .loop import Context, MethodRun, acquisition_factory, check_method_acquisition, config_digest, derive_seed
    from .loop import make_calibration_set, planning_dynamics
    from .methods import build_method
    from .preflight import check_dynamics, check_writable
    from .report import report
    from .rundir import check_run_directory, clean_leftovers, load_calibration, save_calibration
    from .runlock import RunLock
    from .tracking import Tracker

    t0 = time.perf_counter()
    cfg = dict(cfg)
    out = Path(out_dir)
    # ---- validate everything before any compute (and before touching the output directory)
    runner, seeds, single, cfg = run_layout(cfg)
    seed_dirs = {s: out for s in seeds} if single else {s: out / f"seed{s}" for s in seeds}
    progress = bool(cfg.get("progress", True))
    exp, world, planner_cfg, workers = run_settings(cfg)
    make_acq = acquisition_factory(cfg["acquisition"], exp)
    for m in exp.methods:  # the methods: node; every spec instantiates, and fits the acquisition, before compute
        check_method_acquisition(m, build_method(m, cfg["methods"]), make_acq)
    mde_cfg = dict(cfg["mde"])

    def make_mde():
        return instantiate(mde_cfg, _convert_="all")

    mde_module = type(make_mde()).__module__  # validates the MDE config; planner workers import this module up front
    wandb_cfg = dict(cfg.get("wandb", {}))
    if wandb_cfg.get("mode", "offline") not in ("offline", "online", "disabled"):
        raise ValueError(f"wandb.mode = {wandb_cfg.get('mode')!r}: allowed one of ('offline', 'online', 'disabled')")
    check_dynamics(cfg["dynamics"], cfg["world"])  # its config; the cache is writable if the model must be trained
    test_problems = {s: sample_problems(world, exp.test_problems, derive_seed(s, "test"), world="target") for s in seeds}
    check_writable(list(dict.fromkeys([out, *seed_dirs.values()])))

    with contextlib.ExitStack() as stack:
        seed_cfgs, calibrations, cal_paths, accepted = {}, {}, {}, {}
        for s, d in seed_dirs.items():
            stack.enter_context(RunLock(d))  # one writer per run directory; released however this block ends
            seed_cfgs[s] = {**cfg, "seed": s}
            check_writable([d / m for m in exp.methods] + [d / "report"])
            clean_leftovers(d)
            accepted[s], resumable = check_run_directory(d, seed_cfgs[s])
            cal_paths[s] = d / "calibration_set.pt"
            calibrations[s] = load_calibration(cal_paths[s], seed_cfgs[s], accepted[s], trust_untagged=resumable)
        for s, d in seed_dirs.items():  # only now: a refused run leaves every directory's record alone
            write_json(d / "config.json", seed_cfgs[s])
        torch.manual_seed(seeds[0])

        # ---- shared pieces: dynamics model (cached by config hash), simulator, problems, held-out data
        log.info("dynamics model: loading from cache or training (source world only)")
        dyn = planning_dynamics(cfg["dynamics"], cfg["world"], world, exp, progress)
        executor = PouringExecutor(world)
        for s in seeds:
            if calibrations[s] is None:
                calibrations[s] = save_calibration(cal_paths[s], make_calibration_set(
                    world, dyn, executor, ActionSampler(planner_cfg), exp.calibration_trajectories,
                    exp.random_actions_length, s), seed_cfgs[s])
        # planner worker processes (spawned on first use, shared by all methods; results do not depend on them)
        with PlanPool(dyn, planner_cfg, workers, preload=[mde_module]) as pool:
            # the model alone on each seed's test problems (once per seed): the line every method has to beat
            refs = {s: baseline.load(seed_dirs[s] / baseline.FILE, accepted[s], exp.test_problems) for s in seeds}
            missing = {s: test_problems[s] for s in seeds if refs[s] is None}
            if missing:
                log.info("the model alone (no MDE) on the test problems of seed(s) %s", sorted(missing))
                pool.start()
                tb = time.perf_counter()
                for s, rows in baseline.measure(pool, executor, missing, exp.d_max).items():
                    baseline.save(seed_dirs[s] / baseline.FILE, rows, config_digest(seed_cfgs[s]))
                    success, found = baseline.rates(rows)
                    log.info("seed %d, the model alone: plans found %.2f, test success %.2f", s, found, success)
                log.info("the model alone: %.0f s", time.perf_counter() - tb)

            def start(s: int, method: str) -> MethodRun:
                ctx = Context(cfg=seed_cfgs[s], exp=exp, world=world, planner_cfg=planner_cfg, dynamics=dyn,
                              executor=executor, test_problems=test_problems[s], calibration=calibrations[s],
                              out=seed_dirs[s], seed=s, progress=progress, accepted_digests=accepted[s], pool=pool)
                tracker = Tracker(wandb_cfg.get("mode", "offline"), wandb_cfg.get("project", "active-mde"),
                                  f"{exp.name}-{method}-seed{s}", seed_cfgs[s], seed_dirs[s],
                                  entity=wandb_cfg.get("entity"), group=f"{exp.name}-seed{s}")
                return MethodRun(ctx, method, make_mde, make_acq, tracker)

            def report_seed(s: int, runs: list[MethodRun]) -> dict:
                d = seed_dirs[s]
                made = report([d], d / "report")  # figures for W&B and partial runs
                for r in runs:
                    r.tracker.log_images({"learning_curves": d / "report" / "learning_curves.png",
                                          "trajectory_types": d / "report" / "trajectory_types.png"})
                    r.tracker.finish()
                return made

            if runner == "lockstep":
                runs = {s: [start(s, m) for m in exp.methods] for s in seeds}
                run_lockstep([r for s in seeds for r in runs[s]], pool, executor, progress=progress)
                for s in seeds:
                    made = report_seed(s, runs[s])
            else:
                for s in seeds:
                    for method in exp.methods:
                        r = start(s, method)
                        r.run()
                        made = report_seed(s, [r])  # after every method
        executor.close()
    if not single:  # every seed's runs together (one seed: its report is the run's)
        made = report([seed_dirs[s] for s in seeds], out / "report")
    print(made["table"])
    print(f"results and figures in {out} ({time.perf_counter() - t0:.0f} s)")
    return made


def run_layout(cfg: Mapping[str, Any]) -> tuple[str, list[int], bool, dict]:
    """How a run is carried out, validated: ``runner``, its seeds, whether it writes into its directory
    itself (``seeds`` null: the one ``seed``) or into ``seed<s>`` folders; and ``cfg`` without
    ``runner`` and ``seeds`` (each seed directory's ``config.json`` is that of a single-seed run)."""
    from .preflight import check_seed

    c = dict(cfg)
    runner = c.pop("runner", "sequential")
    if runner not in RUNNERS:
        raise ValueError(f"runner = {runner!r}: allowed one of {RUNNERS}")
    seeds = c.pop("seeds", None)
    if seeds is None:
        return runner, [check_seed(c.get("seed"))], True, c
    if isinstance(seeds, (str, bytes, int)) or not hasattr(seeds, "__iter__") or not list(seeds):
        raise ValueError(f"seeds = {seeds!r}: allowed null (the run uses seed) or a non-empty list, e.g. seeds=[0,1,2]")
    seeds = [check_seed(v, f"seeds[{i}]") for i, v in enumerate(seeds)]
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds = {seeds}: allowed each seed at most once")
    return runner, seeds, False, c


def run_settings(cfg: Mapping[str, Any]) -> tuple[Any, Any, Any, int]:
    """What a run of ``cfg`` is set to, validated before any compute: its ``ExperimentConfig``, its
    ``WorldConfig`` (checked against the geometry), the ``PlannerConfig`` every planning call gets and
    the number of planner processes. Errors name the key and what is allowed."""
    from sim.world import WorldConfig

    from .experiment import ExperimentConfig
    from .loop import build_planner_config, planner_workers
    from .preflight import check_geometry

    exp = ExperimentConfig.from_mapping(cfg["experiment"], method=str(cfg.get("method", "all")),
                                       registry=cfg.get("methods"))
    world = WorldConfig.from_mapping(cfg["world"])
    check_geometry(world)
    planner_cfg = build_planner_config(world, cfg["planner"], exp)
    return exp, world, planner_cfg, planner_workers(cfg["planner"])


CONFIG_DIR = configs.CONFIG_DIR


def seed_dir(seed: Any, seeds: Any) -> str:
    """The run directory's last part (the ``seed_dir`` resolver of ``configs/config.yaml``): ``seed0``,
    or ``seeds0-1-2`` for a run of several seeds."""
    return f"seed{seed}" if seeds is None else "seeds" + "-".join(str(s) for s in seeds)


def register_resolvers() -> None:
    """The config's own interpolations (idempotent)."""
    from omegaconf import OmegaConf

    if not OmegaConf.has_resolver("seed_dir"):
        OmegaConf.register_new_resolver("seed_dir", seed_dir)


def compose_config(overrides: list[str] | None = None) -> dict:
    """The resolved config of ``python -m active.run <overrides>`` as a plain dict (no Hydra run dir)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    register_resolvers()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=list(overrides or []))
    plain = OmegaConf.to_container(cfg, resolve=False)
    plain.pop("hydra", None)
    return OmegaConf.to_container(OmegaConf.create(plain), resolve=True)


def _hydra_main() -> None:
    import hydra
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import DictConfig, OmegaConf

    register_resolvers()

    @hydra.main(config_path=str(CONFIG_DIR), config_name="config", version_base="1.3")
    def main(cfg: DictConfig) -> None:
        warnings.filterwarnings("ignore", category=DeprecationWarning)
        plain = OmegaConf.to_container(cfg, resolve=True)
        run_experiment(plain, HydraConfig.get().runtime.output_dir)

    main()


if __name__ == "__main__":
    _hydra_main()
