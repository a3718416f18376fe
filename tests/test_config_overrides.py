"""Every key of the planner and experiment groups acts, every documented override arrives where it acts,
and a key that cannot act is refused before any compute (naming the key and what is allowed).

Composes the config as ``python -m active.run`` does (``active.run.compose_config``) and reads the objects
a run plans and runs with (``active.settings.read_settings``: the ExperimentConfig, the PlannerConfig every
planning call gets, the planner processes). No simulation, no training.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from active.experiment import ExperimentConfig
from active.identity import config_digest
from active.planner_setup import DERIVED_PLANNER_KEYS, NOT_RUN_SETTINGS
from active.run import compose_config, run_experiment
from active.settings import read_settings
from planner import PlannerConfig

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "configs"
PLANNER_YAML = yaml.safe_load((CONFIGS / "planner" / "default.yaml").read_text())
EXPERIMENTS = sorted(p.stem for p in (CONFIGS / "experiment").glob("*.yaml"))

#: a valid value other than the default for every planner-only key (a new key must be added here: shown to act)
PLANNER_ALTERNATIVES = {
    "state_low": [0.04, 0.02, 0.0, 0.0, 0.0],
    "state_high": [0.56, 0.37, 2.5, 1.0, 1.0],
    "p_move": 0.4,
    "goal_bias": 0.1,
    "batch_min": 8,
    "batch_max": 128,
    "last_step_proposals": 16,
    "distance_weights": [1.0, 2.0, 1.0, 1.0],
    "clip_to_bounds": False,
    "prune_dead_states": False,
    "stuck_tilt": 0.1,
    "stuck_move": 0.01,
    "torch_threads": 2,
    "ompl_log_level": "warn",
}
#: for every derived planner key: an override of its source (space-separated overrides) and the value the planner
#: must get
SOURCE_ALTERNATIVES = {
    "move_x": ("world.skills.move.x=[0.12,0.5]", (0.12, 0.5)),
    "move_y": ("world.skills.move.y=[0.07,0.3]", (0.07, 0.3)),
    "pour_theta": ("world.skills.pour.theta=[0.0,2.0]", (0.0, 2.0)),
    "pour_hold": ("world.skills.pour.hold=[0.0,0.8]", (0.0, 0.8)),
    "max_actions": ("world.skills.max_actions=5", 5),
    "spill_limit": ("world.problems.max_spill=0.03 experiment.plan_spill_limit=null", 0.03),  # the default's margin off
    "d_max": ("experiment.d_max=0.05", 0.05),
    "n_candidates": ("experiment.candidates=3", 3),
    "time_budget": ("experiment.planner_time_budget=5.0", 5.0),
    "propagation_budget": ("experiment.planner_propagation_budget=1234", 1234),
}
#: a valid value other than quick's for every experiment key
EXPERIMENT_ALTERNATIVES = {
    "name": "other",
    "methods": ["random_plan"],
    "iterations": 3,
    "trajectories_per_iteration": 3,
    "refit_every": 3,
    "candidates": 3,
    "test_problems": 3,
    "random_actions_length": 3,
    "d_max": 0.05,
    "beta_train": [-1.0, 0.5],
    "beta_switch_iteration": 2,
    "beta_test": 1.5,
    "calibration_trajectories": 3,
    "planner_propagation_budget": 1234,
    "planner_time_budget": 5.0,
    "known_obstacles": False,
    "refine_steps": 2,
    "refine_lr": 0.01,
    "plan_goal_tol": 0.03,
    "plan_spill_limit": 0.01,
    "plan_accept_tol": 0.04,
}


@pytest.fixture(autouse=True)
def _no_geometry_check(monkeypatch):
    """The world's geometry check (about a second of signed distances) is tested elsewhere; not needed here."""
    import active.settings

    monkeypatch.setattr(active.settings, "check_geometry", lambda world: None)


def settings(overrides: list[str]):
    """The typed settings (experiment, world, dynamics, planner, planner processes) of ``python -m active.run
    <overrides>``."""
    return read_settings(compose_config(overrides))


def _override(key: str, value) -> str:
    """``key=value`` in Hydra's override syntax."""

    def fmt(v):
        if isinstance(v, bool):
            return str(v).lower()
        if isinstance(v, (list, tuple)):
            return "[" + ",".join(fmt(x) for x in v) + "]"
        return str(v)

    return f"{key}={fmt(value)}"


# ------------------------------------------------------------------ every key acts
def test_every_planner_key_is_tested_and_planner_only_keys_mirror_the_defaults():
    keys = set(PLANNER_YAML) - {"workers"}
    assert keys == set(PLANNER_ALTERNATIVES) | set(DERIVED_PLANNER_KEYS)
    assert not keys & set(NOT_RUN_SETTINGS)
    assert {f.name for f in dataclasses.fields(PlannerConfig)} == keys | set(NOT_RUN_SETTINGS)
    for k, src in DERIVED_PLANNER_KEYS.items():  # the YAML interpolates exactly the source the check uses
        assert PLANNER_YAML[k] == "${" + src + "}", k


@pytest.mark.parametrize("key", sorted(PLANNER_ALTERNATIVES))
def test_a_planner_only_key_reaches_the_runs_planner_config(key):
    value = PLANNER_ALTERNATIVES[key]
    default = getattr(settings([]).planner, key)
    pc = settings([_override(f"planner.{key}", value)]).planner
    got = getattr(pc, key)
    assert got != default
    assert (list(got) if isinstance(got, tuple) else got) == value


@pytest.mark.parametrize("key", sorted(DERIVED_PLANNER_KEYS))
def test_a_derived_planner_key_follows_its_source_and_is_refused_on_the_planner_side(key):
    override, want = SOURCE_ALTERNATIVES[key]
    pc = settings(override.split()).planner
    assert getattr(pc, key) == want
    src = DERIVED_PLANNER_KEYS[key]
    with pytest.raises(
        ValueError, match=rf"^planner\.{key} = .* differs from {re.escape(src)} = .*set {re.escape(src)}"
    ):
        settings([_override(f"planner.{key}", want)])


@pytest.mark.parametrize("key", sorted(NOT_RUN_SETTINGS))
def test_a_planner_field_that_is_no_run_setting_is_refused(key):
    with pytest.raises(ValueError, match=rf"^planner\.{key} is not a setting of a run"):
        settings([f"+planner.{key}=0.03"])


def test_unknown_keys_are_refused_naming_the_key_and_the_allowed_ones():
    with pytest.raises(ValueError, match=r"unknown planner key\(s\) \['planner.bogus'\]; allowed: \[.*'goal_bias'"):
        settings(["+planner.bogus=1"])
    with pytest.raises(ValueError, match=r"unknown experiment key\(s\) \['bogus'\]; known keys: \[.*'candidates'"):
        settings(["+experiment.bogus=1"])
    from hydra.errors import ConfigCompositionException

    with pytest.raises(ConfigCompositionException, match=r"planner\.bogus"):  # without +: Hydra refuses it
        compose_config(["planner.bogus=1"])


def test_unknown_keys_fail_before_any_compute(tmp_path):
    base = ["experiment=tiny", "wandb.mode=disabled", "progress=false", f"dynamics.cache_root={tmp_path / 'cache'}"]
    for bad, match in (
        ("+planner.bogus=1", r"^planner\.bogus = 1: not a key of planner"),
        ("+planner.beta=1.0", r"^planner\.beta = 1\.0: not a key of planner"),
        ("planner.n_candidates=7", r"^planner\.n_candidates = 7 differs from experiment\.candidates"),
        ("+experiment.bogus=1", r"^experiment\.bogus = 1: not a key of experiment"),
        (
            "+methods.active_balanced.acquisition.cc=0.2",
            r"^methods\.active_balanced\.acquisition\.cc = 0\.2: a parameter of no acquisition",
        ),
        ("method=nope", r"^method = 'nope': allowed one of"),
    ):
        with pytest.raises(ValueError, match=match):
            run_experiment(compose_config(base + [bad]), tmp_path / "out")
    assert not (tmp_path / "out").exists() and not (tmp_path / "cache").exists()


def _refuse_writes_in(folder: Path, monkeypatch) -> None:
    """Make ``folder`` (mode 0o500) refuse new files to root too, as the file system refuses them to everyone else:
    root passes permission checks, so for root the write probe's file creation in it raises the EACCES a regular
    user gets (``active.preflight.check_writable`` probes with ``os.open``)."""
    import errno
    import os

    if os.geteuid() != 0:
        return
    real_open = os.open

    def refusing(path, flags, *args, **kwargs):
        if flags & os.O_CREAT and folder in Path(path).parents:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", refusing)


def test_a_read_only_folder_is_refused_by_the_write_probe(tmp_path, monkeypatch):
    """A folder without write permission is refused naming it and why, and the probe leaves no file behind (as
    root too: see :func:`_refuse_writes_in`)."""
    from active.preflight import check_writable
    from active.runlock import RunDirectoryError

    ro = tmp_path / "ro"
    ro.mkdir(mode=0o500)
    _refuse_writes_in(ro, monkeypatch)
    with pytest.raises(
        RunDirectoryError,
        match=rf"^output directory {re.escape(str(ro))} is not writable "
        r"\(Permission denied\); .*\(hydra\.run\.dir=\.\.\.\)",
    ):
        check_writable([ro])
    with pytest.raises(
        ValueError,
        match=rf"^dynamics cache {re.escape(str(ro))} is not writable \(Permission denied\)"
        r".*\(dynamics\.cache_root=\.\.\.\)",
    ):
        check_writable([ro], what="dynamics cache", field="dynamics.cache_root")
    assert list(ro.iterdir()) == []


def test_a_read_only_run_dir_override_gets_the_projects_message_before_hydra_starts(tmp_path, monkeypatch, capsys):
    """``hydra.run.dir`` inside a folder without write permission: the CLI exits with code 2 and the project's
    message naming the folder and the field, before Hydra creates anything (in-process, so that it runs as root
    too: see :func:`_refuse_writes_in`)."""
    import sys

    import active.run

    ro = tmp_path / "ro"
    ro.mkdir(mode=0o500)
    _refuse_writes_in(ro, monkeypatch)
    target = ro / "run"
    monkeypatch.setattr(
        sys, "argv", ["active.run", "experiment=tiny", "wandb.mode=disabled", f"hydra.run.dir={target}"]
    )
    with pytest.raises(SystemExit) as done:
        active.run.cli()
    assert done.value.code == 2
    err = capsys.readouterr().err
    assert f"output directory {target} is not writable (Permission denied)" in err and "hydra.run.dir=" in err
    assert not (target / ".hydra").exists() and not list(ro.rglob("*.tmp"))


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_every_experiment_yaml_sets_every_key(name):
    data = yaml.safe_load((CONFIGS / "experiment" / f"{name}.yaml").read_text())["experiment"]
    assert set(data) == {f.name for f in dataclasses.fields(ExperimentConfig)}


def test_experiment_defaults_are_the_quick_yaml():
    data = yaml.safe_load((CONFIGS / "experiment" / "quick.yaml").read_text())["experiment"]
    assert ExperimentConfig.from_mapping(data) == ExperimentConfig()
    assert compose_config([])["experiment"]["name"] == "quick"


@pytest.mark.parametrize("key", sorted(EXPERIMENT_ALTERNATIVES))
def test_an_experiment_key_reaches_the_experiment_config(key):
    value = EXPERIMENT_ALTERNATIVES[key]
    exp = settings([_override(f"experiment.{key}", value)]).exp
    got = getattr(exp, key)
    assert (list(got) if isinstance(got, tuple) else got) == value
    assert got != getattr(ExperimentConfig(), key)


# ------------------------------------------------------------------ the documented overrides
def test_documented_overrides_arrive():
    """README's command table, configs/config.yaml, the experiment and planner YAML comments, BENCHMARKS.md."""
    st = settings(["experiment=paper", "method=active_balanced", "seed=2"])
    exp, pc = st.exp, st.planner
    assert (exp.name, exp.methods, exp.iterations, exp.candidates) == ("paper", ("active_balanced",), 20, 9)
    assert (pc.n_candidates, pc.propagation_budget, pc.d_max) == (9, 10000, 0.07)
    assert compose_config(["seed=2"])["seed"] == 2
    assert settings(["experiment.refine_steps=4"]).exp.refine_steps == 4
    for e in EXPERIMENTS:  # README: the model without the known static geometry
        assert settings([f"experiment={e}", "experiment.known_obstacles=false"]).exp.known_obstacles is False
    assert settings(["planner.workers=2"]).workers == 2 and settings(["planner.workers=1"]).workers == 1
    assert settings(["planner.goal_bias=0.1"]).planner.goal_bias == 0.1  # configs/planner/default.yaml
    assert settings(["planner.stuck_move=0.01"]).planner.stuck_move == 0.01  # README: known static geometry
    assert settings(["experiment.plan_goal_tol=0.02"]).planner.goal_tol == 0.02  # BENCHMARKS: ladder rungs
    pc = settings([]).planner  # the default aims at the band's middle with a spill margin
    assert (pc.goal_tol, pc.accept_tol, pc.spill_limit) == (0.025, 0.05, 0.012)
    world_aim = ["experiment.plan_goal_tol=null", "experiment.plan_accept_tol=null", "experiment.plan_spill_limit=null"]
    pc = settings(world_aim).planner  # README: the band-edge planner, the world's band and limit
    assert (pc.goal_tol, pc.accept_tol, pc.spill_limit) == (0.05, None, 0.02)
    assert settings(["experiment.plan_spill_limit=0.01"]).planner.spill_limit == 0.01  # BENCHMARKS: the planner's aim
    pc = settings(["experiment.plan_goal_tol=0.02", "experiment.plan_accept_tol=0.05"]).planner  # BENCHMARKS: the aim
    assert (pc.goal_tol, pc.accept_tol) == (0.02, 0.05)
    with pytest.raises(ValueError, match=r"experiment.plan_accept_tol = 0.06: allowed \(0, 0.05\]"):
        settings(["experiment.plan_accept_tol=0.06"])
    with pytest.raises(ValueError, match=r"experiment.plan_accept_tol = 0.01: allowed"):
        settings(["experiment.plan_goal_tol=0.02", "experiment.plan_accept_tol=0.01"])
    leaf = settings(["world.plant.leaves.0.center=[0.045,0.26]"]).world.plant["leaves"][0]  # README: a higher leaf
    assert list(leaf["center"]) == [0.045, 0.26] and list(leaf["radii"]) == [0.045, 0.007]
    leaf = settings(
        ["world.plant.leaves.0.center=[0.065,0.22]", "world.plant.leaves.0.radii=[0.065,0.007]"]
    ).world.plant["leaves"][0]  # README: the longer leaf, over 60 % of the mouth
    assert list(leaf["center"]) == [0.065, 0.22] and list(leaf["radii"]) == [0.065, 0.007]
    with pytest.raises(ValueError, match=r"experiment.plan_spill_limit = 0.03: allowed \[0, 0.02\]"):
        settings(["experiment.plan_spill_limit=0.03"])
    assert settings(["experiment.planner_propagation_budget=20000"]).planner.propagation_budget == 20000
    st = settings(["world=fine", "world.sim.arch=gpu", "experiment=paper", "method=active_balanced"])
    exp, world, pc = st.exp, st.world, st.planner
    assert world.sim["dx"] == 0.005 and world.sim["arch"] == "gpu" and exp.name == "paper"
    assert (pc.n_candidates, pc.propagation_budget) == (9, 10000)
    pc = settings(["experiment=tiny"]).planner
    assert (pc.n_candidates, pc.propagation_budget, pc.time_budget) == (2, 500, 30.0)
    # README: acquisitions are a config group; your own by _target_ (configs/acquisition/, configs/methods/)
    for group in ("alpha", "lcb", "straddle", "variance"):
        assert compose_config([f"acquisition={group}"])["acquisition"]["_partial_"] is True
    assert compose_config(["acquisition=lcb"])["acquisition"]["_target_"] == "active.acquisition.DiscountedMaxLCB"
    cfg = compose_config(["acquisition._target_=my_acq.WorstStepStd", "method=active_balanced"])
    assert cfg["acquisition"]["_target_"] == "my_acq.WorstStepStd" and cfg["method"] == "active_balanced"
    assert compose_config(["acquisition.gamma=0.9"])["acquisition"]["gamma"] == 0.9
    for m in ("random_actions", "random_plan", "active_cautious", "active_mean", "active_balanced"):
        assert settings([f"method={m}"]).exp.methods == (m,)
    from hydra.utils import instantiate  # README: bound every MDE lengthscale

    assert instantiate(compose_config(["mde.lengthscale_max=2"])["mde"]).config.lengthscale_max == 2.0
    assert instantiate(compose_config(["mde.latent_std_min=0.05"])["mde"]).config.latent_std_min == 0.05


def test_the_acquisition_is_part_of_the_digest():
    """Another acquisition is another configuration: its runs never extend each other's directories."""
    new = compose_config(["experiment=tiny"])
    assert config_digest(compose_config(["experiment=tiny", "acquisition=lcb"])) != config_digest(new)
    assert config_digest(compose_config(["experiment=tiny", "acquisition=variance"])) != config_digest(new)


def test_the_state_box_must_contain_the_action_ranges():
    with pytest.raises(ValueError, match=r"move_y=\[0.06, 0.4\] reaches outside the state bounds of y"):
        settings(["world.skills.move.y=[0.06,0.40]"])
    wider = ["world.skills.move.y=[0.06,0.40]", "planner.state_high=[0.55,0.40,2.4,1.0,1.0]"]
    assert settings(wider).planner.move_y == (0.06, 0.4)


# ------------------------------------------------------------------ the problems
def test_problems_are_the_worlds_and_pinned():
    """The experiment's problems are ``task.sample_problems``' draws (``sim.problems`` names the same function),
    pinned, on and off the world's lattice."""
    from sim.problems import sample_problems as via_sim
    from task import sample_problems

    assert via_sim is sample_problems
    pinned_goals = "world.problems.goal=[0.3,0.8]"  # the goal range of the pinned draws
    cfg = compose_config(["world.skills.lattice=0", pinned_goals])  # continuous positions: the draws themselves
    world = read_settings(cfg).world
    a, b = sample_problems(world, 2, 123), sample_problems(cfg["world"], 2, np.random.default_rng(123))
    # the default world puts the same draws on its 1 cm lattice
    on = sample_problems(read_settings(compose_config([pinned_goals])).world, 2, 123)
    for p, q in zip(a, on):
        np.testing.assert_allclose(q.start[:2], np.round(p.start[:2] / 0.01) * 0.01, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(p.plant_jitter, q.plant_jitter)
        assert p.goal == q.goal
    for p, q in zip(a, b):
        np.testing.assert_array_equal(p.start, q.start)
        np.testing.assert_array_equal(p.plant_jitter, q.plant_jitter)
        assert p.goal == q.goal
    np.testing.assert_array_equal(a[0].start, [0.4555292608547401, 0.08968778338440009, 0.0, 1.0, 0.0])
    np.testing.assert_array_equal(
        a[0].plant_jitter, [-0.004474242035638218, -0.005050051028821285, -0.03240940989149697]
    )
    assert a[0].goal == 0.7060472533278868
    np.testing.assert_array_equal(a[1].start, [0.4892682997237879, 0.12978339160347913, 0.0, 1.0, 0.0])
    assert a[1].goal == 0.4224823005343982 and a[0].world == "target"
    with pytest.raises(ValueError, match="world = 'moon': allowed one of"):
        sample_problems(world, 1, 0, world="moon")


@pytest.mark.parametrize(
    "group, key, value",
    [
        ("mde", "lengthscale_max", 2),
        ("mde", "latent_std_min", 0.05),
        ("mde", "label_max", 0.3),
        ("mde", "latent_std_max", 0.05),
        ("mde", "noise_lengthscale_max", 2),
        ("mde", "hyperparameter_priors", "gamma"),
        ("experiment", "fallback", "model_plan"),
        ("experiment", "plan_goal_tol", 0.02),
        ("experiment", "plan_accept_tol", 0.04),
        ("experiment", "plan_spill_limit", 0.01),
    ],
)
def test_every_result_relevant_key_is_part_of_the_digest(group, key, value):
    """Any other value of a key that changes results is another configuration."""
    new = compose_config(["experiment=tiny"])
    assert config_digest(compose_config(["experiment=tiny", f"{group}.{key}={value}"])) != config_digest(new)


def test_method_specs_are_config_and_arrive_in_the_method_a_run_builds(tmp_path):
    """``methods:`` is part of the run config: an override of a method's c reaches the method object a
    run chooses trajectories with, a new method can be added and selected, and a name that is not in
    the node is refused before compute, naming the allowed ones."""
    from types import SimpleNamespace

    from active.loop import MethodRun
    from active.methods import ActiveChoice, RandomPlan

    def built(overrides: list[str], method: str):
        cfg = compose_config(["experiment=tiny", *overrides])
        pc = read_settings(cfg).planner
        ctx = SimpleNamespace(cfg=cfg, out=tmp_path, planner_cfg=pc)
        return MethodRun(ctx, method, lambda: None, None, None).spec

    assert built([], "active_balanced").acquisition == {"c": 0.1}
    assert built(["methods.active_balanced.acquisition.c=0.25"], "active_balanced").acquisition == {"c": 0.25}
    mine = ["+methods.mine._target_=active.methods.RandomPlan", "method=mine"]
    assert settings(mine).exp.methods == ("mine",) and isinstance(built(mine, "mine"), RandomPlan)
    assert isinstance(built([], "active_mean"), ActiveChoice)
    with pytest.raises(ValueError, match=r"method = 'nope': allowed one of \['active_admission', 'active_balanced'"):
        settings(["method=nope"])
    with pytest.raises(ValueError, match=r"'mine'"):  # experiment.methods names are checked against the node too
        settings(["experiment.methods=[active_balanced,mine]"])


def test_a_method_spec_enters_the_digest_only_for_the_methods_a_run_executes():
    """A changed spec of a method the run executes changes the digest; a change to a method the run does not
    execute does not."""
    base = compose_config(["experiment=tiny"])
    assert config_digest(
        compose_config(["experiment=tiny", "methods.active_balanced.acquisition.c=0.2"])
    ) != config_digest(base)
    assert config_digest(compose_config(["experiment=tiny", "methods.active_mean.acquisition.c=0.2"])) == config_digest(
        base
    )  # tiny runs active_balanced and random_actions only


def test_mde_options_are_the_default_mde_with_named_fields_changed():
    """The default MDE is homoscedastic with labels capped at 0.1 and BoTorch's lognormal priors;
    ``mde=heteroscedastic`` is the paper's GP, fitted by maximum likelihood; every other field as ``mde=default``,
    the same run configuration (digest) as the overrides spelled out. ``mde=maximum_likelihood`` is the default MDE
    fitted by maximum likelihood."""
    from hydra.utils import instantiate

    base, hetero = compose_config(["experiment=tiny"]), compose_config(["experiment=tiny", "mde=heteroscedastic"])
    assert (base["mde"]["heteroscedastic"], base["mde"]["label_max"]) == (False, 0.1)
    assert base["mde"]["hyperparameter_priors"] == "lognormal"
    changed = {k for k in base["mde"] if base["mde"][k] != hetero["mde"].get(k)}
    assert changed == {"heteroscedastic", "label_max", "hyperparameter_priors"} and set(hetero["mde"]) == set(
        base["mde"]
    )
    assert (hetero["mde"]["heteroscedastic"], hetero["mde"]["label_max"]) == (True, None)
    spelled = compose_config(
        ["experiment=tiny", "mde.heteroscedastic=true", "mde.label_max=null", "mde.hyperparameter_priors=none"]
    )
    assert config_digest(hetero) == config_digest(spelled) != config_digest(base)
    ml = compose_config(["experiment=tiny", "mde=maximum_likelihood"])
    assert {k for k in base["mde"] if base["mde"][k] != ml["mde"][k]} == {"hyperparameter_priors"}
    assert config_digest(ml) == config_digest(compose_config(["experiment=tiny", "mde.hyperparameter_priors=none"]))
    assert config_digest(ml) != config_digest(base)
    mde = instantiate(hetero["mde"], _convert_="all")
    assert mde.config.heteroscedastic is True and mde.config.label_max is None
    assert mde.config.hyperparameter_priors == "none"
    default = instantiate(base["mde"], _convert_="all").config
    assert default.heteroscedastic is False and default.hyperparameter_priors == "lognormal"
