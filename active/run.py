"""The experiment runner (the README's main job).

    python -m active.run                                    # experiment=quick: active vs random, seed 0
    python -m active.run experiment=paper method=active_balanced seed=2
    python -m active.run -m method=active_cautious,active_balanced,random_plan seed=0,1,2,3

Writes, under the run directory (``outputs/<experiment>/<method>/seed<seed>`` by default; running the
same command again resumes it): the resolved config, per method ``results.csv``, ``categories.csv``,
``calibration.csv``, ``dataset.pt``, MDE checkpoints and ``state.pt``, and the figures of
``active.report`` in ``report/``. ``run.lock`` names the run writing the directory (a second run
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


def run_experiment(cfg: Mapping[str, Any], out_dir: str | Path) -> dict:
    """Run (or resume) every method of ``cfg`` into ``out_dir``; returns the report summary.

    Order matters: every check runs before any compute (config values, the resolution against the
    geometry, the output and cache locations' writability); then the directory is locked (one
    writer per run directory) and what it holds is checked against ``cfg``; ``config.json`` is
    written only once the directory is accepted.
    """
    import torch
    from hydra.utils import instantiate

    import dynamics
    from planner import ActionSampler
    from planner.pool import PlanPool
    from sim.execute import PouringExecutor
    from task.problems import sample_problems

    from .io import write_json
    from .loop import Context, MethodRun, acquisition_factory, check_method_acquisition, derive_seed, make_calibration_set
    from .methods import build_method
    from .preflight import check_dynamics, check_seed, check_writable
    from .report import report
    from .rundir import check_run_directory, clean_leftovers, load_calibration, save_calibration
    from .runlock import RunLock
    from .tracking import Tracker

    t0 = time.perf_counter()
    cfg = dict(cfg)
    out = Path(out_dir)
    # ---- validate everything before any compute (and before touching the output directory)
    seed = check_seed(cfg.get("seed"))
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
    test_problems = sample_problems(world, exp.test_problems, derive_seed(seed, "test"), world="target")
    check_writable([out])

    with RunLock(out):  # one writer per run directory; released however this block ends
        check_writable([out / m for m in exp.methods] + [out / "report"])
        clean_leftovers(out)
        accepted, resumable = check_run_directory(out, cfg)
        cal_path = out / "calibration_set.pt"
        calibration = load_calibration(cal_path, cfg, accepted, trust_untagged=resumable)  # None: (re)build it
        write_json(out / "config.json", cfg)  # only now: a refused run leaves the directory's record alone
        torch.manual_seed(seed)

        # ---- shared pieces: dynamics model (cached by config hash), simulator, problems, held-out data
        log.info("dynamics model: loading from cache or training (source world only)")
        dyn = dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=progress)
        if exp.known_obstacles:
            dyn = dynamics.ContactAwareDynamics(dyn, world)
        executor = PouringExecutor(world)
        if calibration is None:
            calibration = save_calibration(cal_path, make_calibration_set(
                world, dyn, executor, ActionSampler(planner_cfg), exp.calibration_trajectories,
                exp.random_actions_length, seed), cfg)
        # planner worker processes (spawned on first use, shared by all methods; results do not depend on them)
        with PlanPool(dyn, planner_cfg, workers, preload=[mde_module]) as pool:
            ctx = Context(cfg=cfg, exp=exp, world=world, planner_cfg=planner_cfg, dynamics=dyn, executor=executor,
                          test_problems=test_problems, calibration=calibration, out=out, seed=seed,
                          progress=progress, accepted_digests=accepted, pool=pool)
            for method in exp.methods:
                tracker = Tracker(wandb_cfg.get("mode", "offline"), wandb_cfg.get("project", "active-mde"),
                                  f"{exp.name}-{method}-seed{seed}", cfg, out, entity=wandb_cfg.get("entity"),
                                  group=f"{exp.name}-seed{seed}")
                MethodRun(ctx, method, make_mde, make_acq, tracker).run()
                made = report([out], out / "report")  # after every method: figures for W&B and partial runs
                tracker.log_images({"learning_curves": out / "report" / "learning_curves.png",
                                    "trajectory_types": out / "report" / "trajectory_types.png"})
                tracker.finish()
        executor.close()
    print(made["table"])
    print(f"results and figures in {out} ({time.perf_counter() - t0:.0f} s)")
    return made


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


def compose_config(overrides: list[str] | None = None) -> dict:
    """The resolved config of ``python -m active.run <overrides>`` as a plain dict (no Hydra run dir)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=list(overrides or []))
    plain = OmegaConf.to_container(cfg, resolve=False)
    plain.pop("hydra", None)
    return OmegaConf.to_container(OmegaConf.create(plain), resolve=True)


def _hydra_main() -> None:
    import hydra
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import DictConfig, OmegaConf

    @hydra.main(config_path=str(CONFIG_DIR), config_name="config", version_base="1.3")
    def main(cfg: DictConfig) -> None:
        warnings.filterwarnings("ignore", category=DeprecationWarning)
        plain = OmegaConf.to_container(cfg, resolve=True)
        run_experiment(plain, HydraConfig.get().runtime.output_dir)

    main()


if __name__ == "__main__":
    _hydra_main()
