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

import contextlib
import logging
import os
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

# OpenMP threads that spin while waiting stall each other (and the simulator's threads) on small
# machines shared with other jobs; passive waiting costs nothing measurable on an idle machine.
# Set before torch and Taichi are imported (below), which read it when their thread pools start.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import hydra  # noqa: E402
import torch  # noqa: E402
from hydra import compose, initialize_config_dir  # noqa: E402
from hydra.core.hydra_config import HydraConfig  # noqa: E402
from hydra.utils import instantiate  # noqa: E402
from omegaconf import DictConfig, OmegaConf  # noqa: E402

import configs  # noqa: E402
import safeio  # noqa: E402
from configs.schema import check_config  # noqa: E402
from dynamics import DynamicsConfig  # noqa: E402
from planner import ActionSampler, PlannerConfig  # noqa: E402
from planner.pool import PlanPool  # noqa: E402
from sim.execute import PouringExecutor  # noqa: E402
from sim.world import WorldConfig  # noqa: E402
from task.problems import sample_problems  # noqa: E402

from . import baseline  # noqa: E402
from .acquisition_factory import acquisition_factory, check_method_acquisition  # noqa: E402
from .calibration import load_calibration, make_calibration_set, save_calibration  # noqa: E402
from .experiment import ExperimentConfig  # noqa: E402
from .identity import config_digest  # noqa: E402
from .io import write_json  # noqa: E402
from .lockstep import run_lockstep  # noqa: E402
from .loop import Context, MethodRun  # noqa: E402
from .methods import build_method  # noqa: E402
from .oracle import BOUND_NAMES  # noqa: E402
from .planner_setup import planning_dynamics  # noqa: E402
from .preflight import check_dynamics, check_seed, check_writable  # noqa: E402
from .report import report  # noqa: E402
from .rundir import check_run_directory, clean_leftovers  # noqa: E402
from .runlock import RunDirectoryError, RunLock  # noqa: E402
from .seeds import derive_seed  # noqa: E402
from .settings import read_settings  # noqa: E402
from .tracking import Tracker  # noqa: E402

log = logging.getLogger("active.run")


RUNNERS = ("sequential", "lockstep")
WANDB_MODES = ("offline", "online", "disabled")


@dataclass
class RunSpec:
    """Everything a run is set to, validated before any compute (:func:`prepare_run`)."""

    cfg: dict
    runner: str
    seeds: list[int]
    single: bool  # one seed, written into the run directory itself (not seed<s>/)
    seed_dirs: dict[int, Path]
    exp: ExperimentConfig
    world: WorldConfig
    dynamics: DynamicsConfig
    planner_cfg: PlannerConfig
    workers: int
    make_acq: Callable
    make_mde: Callable
    mde_module: str
    wandb: dict
    test_problems: dict
    progress: bool

    def seed_cfg(self, s: int) -> dict:
        """The configuration of seed ``s``'s directory (that of a single-seed run with ``seed=s``)."""
        return {**self.cfg, "seed": s}


def run_experiment(
    cfg: Mapping[str, Any], out_dir: str | Path, on_accept: Callable[[Path], None] | None = None
) -> dict:
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
    written only once the directory is accepted, and so are the files ``on_accept(out_dir)`` writes (the
    Hydra entry point's ``.hydra/`` record).
    """
    t0 = time.perf_counter()
    out = Path(out_dir)
    spec = prepare_run(cfg, out)
    with contextlib.ExitStack() as stack:
        calibrations = accept_directories(spec, stack)
        if on_accept is not None:
            on_accept(out)
        torch.manual_seed(spec.seeds[0])
        log.info("dynamics model: loading from cache or training (source world only)")
        dyn = planning_dynamics(spec.dynamics, spec.world, spec.exp, spec.progress)
        executor = PouringExecutor(spec.world)
        for s in spec.seeds:
            if calibrations[s] is None:
                calibrations[s] = save_calibration(
                    spec.seed_dirs[s] / "calibration_set.pt",
                    make_calibration_set(
                        spec.world,
                        dyn,
                        executor,
                        ActionSampler(spec.planner_cfg),
                        spec.exp.calibration_trajectories,
                        spec.exp.random_actions_length,
                        s,
                    ),
                    spec.seed_cfg(s),
                )
        # planner worker processes (spawned on first use, shared by all methods; results do not depend on them)
        with PlanPool(dyn, spec.planner_cfg, spec.workers, preload=[spec.mde_module]) as pool:
            measure_model_alone(spec, pool, executor)
            made = run_methods(spec, _contexts(spec, dyn, executor, calibrations, pool), pool, executor)
        executor.close()
    if not spec.single:  # every seed's runs together (one seed: its report is the run's)
        made = report([spec.seed_dirs[s] for s in spec.seeds], out / "report")
    print(made["table"])
    print(f"results and figures in {out} ({time.perf_counter() - t0:.0f} s)")
    return made


def prepare_run(cfg: Mapping[str, Any], out: Path) -> RunSpec:
    """Validate everything before any compute and before touching the output directory."""
    check_config(cfg)  # every leaf's type, finiteness, range and choices, named by its full path (configs.schema)
    runner, seeds, single, cfg = run_layout(cfg)
    seed_dirs = {s: out for s in seeds} if single else {s: out / f"seed{s}" for s in seeds}
    settings = read_settings(cfg)
    exp, world = settings.exp, settings.world
    make_acq = acquisition_factory(cfg["acquisition"], exp)
    for m in exp.methods:  # the methods: node; every spec instantiates, and fits the acquisition, before compute
        check_method_acquisition(m, build_method(m, cfg["methods"]), make_acq)
    mde_cfg = dict(cfg["mde"])

    def make_mde() -> Any:
        return instantiate(mde_cfg, _convert_="all")

    mde_module = type(make_mde()).__module__  # validates the MDE config; planner workers import this module up front
    wandb_cfg = dict(cfg.get("wandb", {}))
    if wandb_cfg.get("mode", "offline") not in WANDB_MODES:
        raise ValueError(f"wandb.mode = {wandb_cfg.get('mode')!r}: allowed one of {WANDB_MODES}")
    check_dynamics(settings.dynamics, world)  # the cache is writable if the model must be trained
    test_problems = {
        s: sample_problems(world, exp.test_problems, derive_seed(s, "test"), world="target") for s in seeds
    }
    check_writable(list(dict.fromkeys([out, *seed_dirs.values()])))
    return RunSpec(
        cfg=cfg,
        runner=runner,
        seeds=seeds,
        single=single,
        seed_dirs=seed_dirs,
        exp=exp,
        world=world,
        dynamics=settings.dynamics,
        planner_cfg=settings.planner,
        workers=settings.workers,
        make_acq=make_acq,
        make_mde=make_mde,
        mde_module=mde_module,
        wandb=wandb_cfg,
        test_problems=test_problems,
        progress=bool(cfg.get("progress", True)),
    )


def accept_directories(spec: RunSpec, stack: contextlib.ExitStack) -> dict[int, dict | None]:
    """Lock every seed's directory (released when ``stack`` closes), check what it holds against its
    configuration, and only then record the configuration; returns each seed's reusable calibration set."""
    calibrations = {}
    for s, d in spec.seed_dirs.items():
        stack.enter_context(RunLock(d))  # one writer per run directory; released however the run ends
        check_writable([d / m for m in spec.exp.methods] + [d / "report"])
        clean_leftovers(d)
        check_run_directory(d, spec.seed_cfg(s))
        calibrations[s] = load_calibration(d / "calibration_set.pt", spec.seed_cfg(s))
    for s, d in spec.seed_dirs.items():  # only now: a refused run leaves every directory's record alone
        write_json(d / "config.json", spec.seed_cfg(s))
    return calibrations


def measure_model_alone(spec: RunSpec, pool: PlanPool, executor: PouringExecutor) -> None:
    """The model alone on each seed's test problems (once per seed): the line every method has to beat."""
    digests = {s: config_digest(spec.seed_cfg(s)) for s in spec.seeds}
    missing = {
        s: spec.test_problems[s]
        for s in spec.seeds
        if baseline.load(spec.seed_dirs[s] / baseline.FILE, digests[s], spec.exp.test_problems) is None
    }
    if not missing:
        return
    log.info("the model alone (no MDE) on the test problems of seed(s) %s", sorted(missing))
    pool.start()
    tb = time.perf_counter()
    for s, rows in baseline.measure(pool, executor, missing, spec.exp.d_max).items():
        baseline.save(spec.seed_dirs[s] / baseline.FILE, rows, digests[s])
        success, found = baseline.rates(rows)
        log.info("seed %d, the model alone: plans found %.2f, test success %.2f", s, found, success)
    log.info("the model alone: %.0f s", time.perf_counter() - tb)


def _contexts(spec: RunSpec, dyn: Any, executor: PouringExecutor, calibrations: dict, pool: PlanPool) -> dict:
    """Each seed's :class:`Context` (what every method of the seed shares)."""
    return {
        s: Context(
            cfg=spec.seed_cfg(s),
            exp=spec.exp,
            world=spec.world,
            planner_cfg=spec.planner_cfg,
            dynamics=dyn,
            executor=executor,
            test_problems=spec.test_problems[s],
            calibration=calibrations[s],
            out=spec.seed_dirs[s],
            seed=s,
            progress=spec.progress,
            pool=pool,
        )
        for s in spec.seeds
    }


def run_methods(spec: RunSpec, contexts: dict[int, Context], pool: PlanPool, executor: PouringExecutor) -> dict:
    """Every (method, seed) to ``experiment.iterations``, in lockstep or one after another, each seed's report
    drawn as its runs finish; returns the last report made."""
    exp = spec.exp

    def start(s: int, method: str) -> MethodRun:
        tracker = Tracker(
            spec.wandb.get("mode", "offline"),
            spec.wandb.get("project", "active-mde"),
            f"{exp.name}-{method}-seed{s}",
            spec.seed_cfg(s),
            spec.seed_dirs[s],
            entity=spec.wandb.get("entity"),
            group=f"{exp.name}-{method}",
            run_id=f"{config_digest(spec.seed_cfg(s))}-{method}-seed{s}",
        )
        return MethodRun(contexts[s], method, spec.make_mde, spec.make_acq, tracker)

    def report_seed(s: int, runs: list[MethodRun]) -> dict:
        d = spec.seed_dirs[s]
        made = report([d], d / "report")  # figures for W&B and partial runs
        for r in runs:
            r.tracker.log_images(
                {
                    "learning_curves": d / "report" / "learning_curves.png",
                    "trajectory_types": d / "report" / "trajectory_types.png",
                }
            )
            r.tracker.finish()
        return made

    made: dict = {}
    if spec.runner == "lockstep":
        runs = {s: [start(s, m) for m in exp.methods] for s in spec.seeds}
        run_lockstep([r for s in spec.seeds for r in runs[s]], pool, executor, progress=spec.progress)
        for s in spec.seeds:
            made = report_seed(s, runs[s])
    else:
        for s in spec.seeds:
            for method in exp.methods:
                r = start(s, method)
                r.run()
                made = report_seed(s, [r])  # after every method
    return made


def run_layout(cfg: Mapping[str, Any]) -> tuple[str, list[int], bool, dict]:
    """How a run is carried out, validated: ``runner``, its seeds, whether it writes into its directory
    itself (``seeds`` null: the one ``seed``) or into ``seed<s>`` folders; and ``cfg`` without
    ``runner`` and ``seeds`` (each seed directory's ``config.json`` is that of a single-seed run)."""
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


CONFIG_DIR = configs.CONFIG_DIR


def seed_dir(seed: Any, seeds: Any) -> str:
    """The run directory's last part (the ``seed_dir`` resolver of ``configs/config.yaml``): ``seed0``,
    or ``seeds0-1-2`` for a run of several seeds."""
    return f"seed{seed}" if seeds is None else "seeds" + "-".join(str(s) for s in seeds)


def run_subdir(overrides: str, method: Any, seed: Any, seeds: Any) -> str:
    """The run directory below the experiment's folder (the ``run_subdir`` resolver): the result-changing overrides
    (``hydra.job.override_dirname``; no level when there are none), the method, the seed: ``all/seed0``,
    ``mde.label_max=0.15/all/seed0``."""
    return "/".join(part for part in (overrides, str(method), seed_dir(seed, seeds)) if part)


def register_resolvers() -> None:
    """The config's own interpolations (idempotent)."""
    if not OmegaConf.has_resolver("seed_dir"):
        OmegaConf.register_new_resolver("seed_dir", seed_dir)
    if not OmegaConf.has_resolver("run_subdir"):
        OmegaConf.register_new_resolver("run_subdir", run_subdir)


def compose_config(overrides: list[str] | None = None) -> dict:
    """The resolved config of ``python -m active.run <overrides>`` as a plain dict (no Hydra run dir)."""
    register_resolvers()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=list(overrides or []))
    plain = OmegaConf.to_container(cfg, resolve=False)
    plain.pop("hydra", None)
    return OmegaConf.to_container(OmegaConf.create(plain), resolve=True)


def headline(made: Mapping[str, Any]) -> float | None:
    """The run's headline metric, what a Hydra sweeper (Optuna, Ax) optimises: the best method's area under the
    test-success curve (mean over seeds), or None before any iteration completed. A bound (``oracle``) is no method."""
    aucs = [row["auc_success"] for row in made.get("summary", []) if row["method"] not in BOUND_NAMES]
    return float(max(aucs)) if aucs else None


def hydra_record(cfg: DictConfig) -> Callable[[Path], None]:
    """A writer of Hydra's record of the job (``.hydra/config.yaml``, ``overrides.yaml``, ``hydra.yaml``; the config
    sets ``hydra.output_subdir: null`` so that Hydra does not write them when it starts) that also opens the job's
    ``run.log`` (``hydra/job_logging: console`` has no file handler), called once the run directory is accepted: a
    refused run leaves the accepted run's record and log as they were."""

    def write(out: Path) -> None:
        hc = HydraConfig.get()
        record = out / ".hydra"
        record.mkdir(parents=True, exist_ok=True)
        safeio.write_text(record / "hydra.yaml", OmegaConf.to_yaml({"hydra": hc}))
        safeio.write_text(record / "overrides.yaml", OmegaConf.to_yaml(list(hc.overrides.task)))
        safeio.write_text(record / "config.yaml", OmegaConf.to_yaml(cfg))
        log_file = logging.FileHandler(out / "run.log")
        log_file.setFormatter(logging.Formatter("[%(asctime)s][%(name)s][%(levelname)s] - %(message)s"))
        logging.getLogger().addHandler(log_file)

    return write


def hydra_run_dir(argv: list[str]) -> Path | None:
    """The run directory ``python -m active.run <argv>`` will write (None for a multirun or a bad override: Hydra
    reports those itself), composed as Hydra will, so that it is checked before Hydra creates it."""
    if any(a in ("-m", "--multirun") or a.startswith("--") for a in argv):
        return None
    register_resolvers()
    try:
        with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
            cfg = compose(config_name="config", overrides=list(argv), return_hydra_config=True)
        return Path(str(cfg.hydra.run.dir))
    except Exception:  # noqa: BLE001 - Hydra's own error messages for bad overrides are the right ones
        return None


def cli() -> None:
    """``active-mde`` / ``python -m active.run``: the Hydra entry point (overrides on the command line)."""
    register_resolvers()
    run_dir = hydra_run_dir(sys.argv[1:])
    if run_dir is not None:
        try:
            check_writable([run_dir])
        except RunDirectoryError as e:  # before Hydra creates the folder (its error would be a raw traceback)
            print(f"active.run: {e}", file=sys.stderr)
            raise SystemExit(2) from None

    @hydra.main(config_path=str(CONFIG_DIR), config_name="config", version_base="1.3")
    def main(cfg: DictConfig) -> float | None:
        warnings.filterwarnings("ignore", category=DeprecationWarning)
        plain = OmegaConf.to_container(cfg, resolve=True)
        made = run_experiment(plain, HydraConfig.get().runtime.output_dir, on_accept=hydra_record(cfg))
        return headline(made)

    main()


if __name__ == "__main__":
    cli()
