"""Every leaf of the run config is checked before compute (configs/schema.py): a wrong type, NaN, an infinity or a
value out of range is refused with a message that names the field's full dotted path, the value and what is
allowed, before any cache or run file is written; every shipped config passes.

The leaves are found by walking the composed presets, not listed by hand, so a new key is covered (and a key the
schema does not know fails here)."""

from __future__ import annotations

import copy
import dataclasses
import importlib
import inspect
import math
from pathlib import Path

import pytest

from active.run import compose_config, run_experiment
from configs import schema
from configs.schema import ConfigFieldError, check_config, format_path, rule_for

PRESETS = ("quick", "paper", "tiny")
CONFIGS = Path(schema.__file__).resolve().parent
#: every option of every config group (configs/<group>/<option>.yaml)
OPTIONS = sorted(f"{p.parent.name}={p.stem}" for p in CONFIGS.glob("*/*.yaml"))


def leaves(node, loc=()):
    """(loc, value) of every leaf of a composed config (numbers inside lists included)."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from leaves(v, (*loc, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from leaves(v, (*loc, i))
    else:
        yield loc, node


def groups(node, loc=()):
    """The loc of every mapping (config group) of a composed config, the root included."""
    if isinstance(node, dict):
        yield loc
        for k, v in node.items():
            yield from groups(v, (*loc, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from groups(v, (*loc, i))


def with_value(cfg: dict, loc: tuple, value) -> dict:
    out = copy.deepcopy(cfg)
    node = out
    for part in loc[:-1]:
        node = node[part]
    node[loc[-1]] = value
    return out


def is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def outside(rule: schema.Rule) -> list:
    """Values just outside each bound the schema declares for a leaf (and outside its numeric choices)."""
    step = 1 if rule.integer else 1e-9
    out = []
    if rule.gt is not None:
        out.append(rule.gt)
    if rule.ge is not None:
        out.append(rule.ge - step * max(1.0, abs(rule.ge)) if not rule.integer else rule.ge - 1)
    if rule.lt is not None:
        out.append(rule.lt)
    if rule.le is not None:
        out.append(rule.le + step * max(1.0, abs(rule.le)) if not rule.integer else rule.le + 1)
    if rule.choices and all(is_number(c) for c in rule.choices):
        out.append(max(rule.choices) + 1)
    return out


def refusal(cfg: dict) -> str | None:
    """check_config's message for ``cfg``, or None if it passes."""
    try:
        assert check_config(cfg) is cfg
    except ConfigFieldError as e:
        assert isinstance(e, ValueError)
        return str(e)
    return None


@pytest.fixture(scope="module")
def presets() -> dict[str, dict]:
    return {p: compose_config([f"experiment={p}"]) for p in PRESETS}


# ------------------------------------------------------------------ no false refusal
@pytest.mark.parametrize("option", OPTIONS)
def test_every_shipped_config_option_passes(option):
    cfg = compose_config([option])
    assert refusal(cfg) is None
    assert check_config(cfg) is cfg  # returned as it is: the run keeps using its mappings


def test_every_preset_passes_and_every_leaf_has_a_rule(presets):
    for name, cfg in presets.items():
        assert refusal(cfg) is None, name
        missing = [format_path(loc) for loc, _ in leaves(cfg) if rule_for(format_path(loc)) is None]
        assert not missing, f"experiment={name}: leaves without a rule in configs/schema.py: {missing}"


def test_valid_values_of_another_form_pass(presets):
    """Integers pass as floats, tuples as lists; the optional fields take null."""
    cfg = presets["quick"]
    for loc, value in [
        (("experiment", "d_max"), 1),
        (("world", "skills", "move", "x"), (0.1, 0.5)),
        (("experiment", "plan_goal_tol"), None),
        (("mde", "group_column"), None),
        (("seeds",), [0, 1, 2]),
        (("planner", "workers"), 3),
        (("world", "sim", "arch"), "gpu"),
    ]:
        assert refusal(with_value(cfg, (loc), value)) is None, format_path(loc)
    custom = [
        "acquisition._target_=my_acq.WorstStepStd",
        "+acquisition.width=3",
        "+methods.active_balanced.acquisition.width=2",
        "+methods.mine._target_=my_methods.Mine",
        "+methods.mine.k=3",
        "method=mine",
    ]
    assert refusal(compose_config(custom)) is None  # a custom class's parameters are its own


# ------------------------------------------------------------------ every numeric leaf refused when wrong
@pytest.mark.parametrize("preset", PRESETS)
def test_every_numeric_leaf_refuses_a_bad_value_naming_its_path(presets, preset):
    cfg = presets[preset]
    numeric = [(loc, v) for loc, v in leaves(cfg) if is_number(v)]
    assert len(numeric) > 150  # the walk found the tree (world, dynamics, mde, planner, experiment, methods, ...)
    failures, probed = [], 0
    for loc, value in numeric:
        path = format_path(loc)
        rule = rule_for(path)
        if rule is None:
            failures.append(f"{path}: no rule in configs/schema.py")
            continue
        bad = ["abc", math.nan, math.inf, -math.inf, True, *outside(rule)]
        if rule.integer:
            bad.append(float(value) + 0.5)
        for b in bad:
            probed += 1
            msg = refusal(with_value(cfg, loc, b))
            if msg is None:
                failures.append(f"{path} = {b!r}: accepted")
            elif f"{path} = {b!r}: " not in msg or "allowed" not in msg:
                failures.append(f"{path} = {b!r}: refused without naming it: {msg}")
    assert not failures, f"experiment={preset}, {len(failures)} of {probed} probes:\n" + "\n".join(failures)


@pytest.mark.parametrize("preset", PRESETS)
def test_every_string_and_boolean_leaf_refuses_a_wrong_value(presets, preset):
    cfg = presets[preset]
    failures = []
    for loc, value in leaves(cfg):
        path = format_path(loc)
        rule = rule_for(path)
        if isinstance(value, bool):
            bad = ["yes", 1, None]
        elif isinstance(value, str) and rule.choices:
            bad = ["moon", 1, None]
        elif isinstance(value, str):
            bad = [1.5, None, ""]
        else:
            continue
        for b in bad:
            msg = refusal(with_value(cfg, loc, b))
            if msg is None or f"{path} = {b!r}: " not in msg:
                failures.append(f"{path} = {b!r}: {msg}")
    assert not failures, "\n".join(failures)


@pytest.mark.parametrize(
    "override, line",
    [
        ("world.sim.arch=moon", "world.sim.arch = 'moon': allowed one of ('cpu', 'gpu', 'auto')"),
        ("runner=x", "runner = 'x': allowed one of ('sequential', 'lockstep')"),
        ("mde.predict_dtype=float16", "mde.predict_dtype = 'float16': allowed one of ('float32', 'float64')"),
        ("mde.nu=2.0", "mde.nu = 2.0: allowed one of (0.5, 1.5, 2.5)"),
        (
            "world.plant.on_contact=bounce",
            "world.plant.on_contact = 'bounce': allowed one of ('stop', 'hold', 'stuck')",
        ),
        ("experiment.fallback=plans", "experiment.fallback = 'plans': allowed one of ('random_actions', 'model_plan')"),
        ("planner.workers=many", "planner.workers = 'many': allowed an integer >= 1"),
        ("method=nope", "method = 'nope': allowed one of ['active_admission'"),
        ("experiment.methods=[random_plan,nope]", "experiment.methods[1] = 'nope': allowed one of ['active_admission'"),
        (
            "world.skills.move.x=[0.5,0.1]",
            "world.skills.move.x = [0.5, 0.1]: allowed a [low, high] pair with low <= high",
        ),
        ("world.problems.goal=[0.3,1.2]", "world.problems.goal[1] = 1.2: allowed [0, 1]"),
        ("experiment.beta_train=[1.0]", "experiment.beta_train = [1.0]: allowed [beta_early, beta_late]"),
        (
            "planner.distance_weights=[0,0,0,0]",
            "planner.distance_weights = [0, 0, 0, 0]: allowed 4 finite numbers >= 0",
        ),
        ("planner.batch_min=512", "planner.batch_max = 256: allowed an integer >= batch_min = 512"),
        ("seeds=[0,0]", "seeds = [0, 0]: allowed each seed at most once"),
        ("mde.max_fit_points=1", "mde.max_fit_points = 1: allowed 0 (all points) or an integer >= 2"),
        (
            "acquisition=admission +acquisition.gamma=0.5",
            "acquisition.gamma = 0.5: not a parameter of active.acquisition.TrajectoryAdmissionGain",
        ),
        (
            "+methods.active_balanced.acquisition.cc=0.2",
            "methods.active_balanced.acquisition.cc = 0.2: a parameter of no acquisition",
        ),
        (
            "+methods.random_plan.acquisition.c=0.2",
            "methods.random_plan.acquisition = {'c': 0.2}: not a parameter of active.methods.RandomPlan",
        ),
        ("acquisition._target_=not-a-path", "acquisition._target_ = 'not-a-path': allowed a dotted import path"),
    ],
)
def test_choices_pairs_and_names_are_refused_saying_what_is_allowed(override, line):
    msg = refusal(compose_config(override.split()))
    assert msg is not None and line in msg, msg


def test_an_unknown_key_is_refused_in_every_group(presets):
    cfg = presets["tiny"]
    failures = []
    for loc in groups(cfg):
        path = format_path((*loc, "bogus_key"))
        msg = refusal(with_value(cfg, (*loc, "bogus_key"), 1))
        if msg is None or f"{path} = 1: " not in msg:
            failures.append(f"{path}: {msg}")
    assert not failures, "\n".join(failures)
    msg = refusal(with_value(cfg, ("world", "sim", "bogus_key"), 1))
    assert "not a key of world.sim; allowed keys: ['arch'," in msg


def test_the_message_has_one_line_per_field(presets):
    cfg = with_value(with_value(presets["tiny"], ("world", "sim", "dx"), "abc"), ("experiment", "beta_test"), math.nan)
    with pytest.raises(ConfigFieldError) as e:
        check_config(cfg)
    assert str(e.value).splitlines() == [
        "world.sim.dx = 'abc': allowed > 0 (a finite number)",
        "experiment.beta_test = nan: allowed a finite number",
    ]
    assert [f[0] for f in e.value.fields] == ["world.sim.dx", "experiment.beta_test"]


# ------------------------------------------------------------------ refused before compute
@pytest.mark.parametrize(
    "override, line",
    [
        ("experiment.beta_test=abc", "experiment.beta_test = 'abc': allowed a finite number"),
        ("experiment.beta_test=nan", "experiment.beta_test = nan: allowed a finite number"),
        ("experiment.d_max=abc", "experiment.d_max = 'abc': allowed > 0"),
        ("world.sim.dx=abc", "world.sim.dx = 'abc': allowed > 0"),
        ("dynamics.train.lr=abc", "dynamics.train.lr = 'abc': allowed > 0"),
        ("world.problems.tolerance=abc", "world.problems.tolerance = 'abc': allowed (0, 1]"),
        ("experiment.beta_train=[a,1]", "experiment.beta_train[0] = 'a': allowed a finite number"),
    ],
)
def test_a_run_refuses_before_writing_anything(tmp_path, override, line):
    cfg = compose_config(
        [
            "experiment=tiny",
            "wandb.mode=disabled",
            "progress=false",
            f"dynamics.cache_root={tmp_path / 'cache'}",
            override,
        ]
    )
    with pytest.raises(ConfigFieldError) as e:
        run_experiment(cfg, tmp_path / "out")
    assert line in str(e.value)
    assert not (tmp_path / "out").exists() and not (tmp_path / "cache").exists()


# ------------------------------------------------------------------ the schema agrees with the code
def test_the_choices_are_those_of_the_consuming_code():
    import active.experiment
    import active.preflight
    import active.run
    import dynamics.config
    import mde.config
    import planner.config
    import sim.world

    sim_config = importlib.import_module(sim.world.SimConfig.__module__)
    assert (schema.ARCHES, schema.BOX_NORMALS) == (sim_config.ARCHES, sim_config.BOX_NORMALS)
    assert schema.PLANT_CONTACT == sim.world.PLANT_CONTACT
    assert (schema.ACTIVATIONS, schema.LOSSES, schema.LR_SCHEDULES) == (
        dynamics.config.ACTIVATIONS,
        dynamics.config.LOSSES,
        dynamics.config.LR_SCHEDULES,
    )
    assert (schema.NU, schema.INPUT_SCALING, schema.PREDICT_DTYPES, schema.PRIORS) == (
        mde.config.ALLOWED_NU,
        mde.config.ALLOWED_INPUT_SCALING,
        mde.config.ALLOWED_PREDICT_DTYPE,
        mde.config.ALLOWED_PRIORS,
    )
    assert set(schema.OMPL_LOG_LEVELS) == planner.config._LOG_LEVELS
    assert schema.FALLBACKS == active.experiment.ALLOWED_FALLBACKS
    assert (schema.RUNNERS, schema.WANDB_MODES) == (active.run.RUNNERS, active.run.WANDB_MODES)
    assert schema.MAX_SEED == active.preflight.MAX_SEED


def _params(cls) -> set[str]:
    return {
        k
        for k, p in inspect.signature(cls.__init__).parameters.items()
        if k != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
    }


def test_the_built_in_parameters_are_those_of_the_classes():
    from active.acquisition import ACQUISITIONS

    assert schema.ACQUISITION_PARAMS == {
        f"{c.__module__}.{c.__name__}": schema.ACQUISITION_PARAMS[f"{c.__module__}.{c.__name__}"]
        for c in ACQUISITIONS.values()
    }
    for c in ACQUISITIONS.values():  # model and reference are the loop's
        assert set(schema.ACQUISITION_PARAMS[f"{c.__module__}.{c.__name__}"]) == _params(c) - {"model", "reference"}
    for target, params in schema.METHOD_PARAMS.items():
        module, name = target.rsplit(".", 1)
        assert set(params) == _params(getattr(importlib.import_module(module), name)), target


def test_the_groups_have_the_keys_of_the_consuming_dataclasses():
    from active.experiment import ExperimentConfig
    from active.planner_setup import NOT_RUN_SETTINGS
    from dynamics.config import DataConfig, EvalConfig, ModelConfig, TrainConfig
    from mde.config import MDEConfig
    from planner.config import PlannerConfig
    from sim.world import SimConfig

    def keys(model) -> set[str]:
        return {f.alias or k for k, f in model.model_fields.items()}

    def names(cls) -> set[str]:
        return {f.name for f in dataclasses.fields(cls)}

    assert keys(schema.Sim) == names(SimConfig) - {"n_envs"}  # n_envs: each simulator call's own
    assert keys(schema.Experiment) == names(ExperimentConfig)
    assert keys(schema.Data) == names(DataConfig) and keys(schema.Model) == names(ModelConfig)
    assert keys(schema.Train) == names(TrainConfig) and keys(schema.Eval) == names(EvalConfig)
    assert keys(schema.MDE) == names(MDEConfig) | {"_target_"}
    assert keys(schema.Planner) == (names(PlannerConfig) - set(NOT_RUN_SETTINGS)) | {"_target_", "workers"}
