"""The default source-world dataset and models, shipped with the package so that a first run need not
simulate or train them.

Generating the default training data takes tens of minutes of simulation on a 2-core CPU and
training the default ensemble's members about a minute each; the files are small (a few thousand
transitions; a few hundred kB per model), so the package carries them under ``dynamics/shipped/``
with the hash of the configuration that made them in their names (``source-<data_hash>.pt``,
``model-<model_hash>.pt``; a model hash covers its data hash). The cache (:mod:`dynamics.train`) uses a
shipped file only when its hash equals the one the requested configuration needs; a shipped file made by
another configuration (a changed world, solver, data, model or training setting) is reported and never
used: the data is then simulated, the model trained.

    python -m dynamics.shipped            # regenerate the shipped files for the default config
    python -m dynamics.shipped --check    # say whether the shipped files match the default config

``tests/test_dynamics_shipped.py`` regenerates one shard on the CPU and compares it bit for bit,
and (marked ``slow``) retrains a shipped member and compares its predictions.
"""

from __future__ import annotations

import argparse
import logging
from typing import Any, Sequence

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import safeio

from .config import DynamicsConfig, DynamicsError, single_models
from .data import Transitions
from .model import LearnedDynamics
from .train import (
    CONFIG_DIR,
    SHIPPED_DIR,
    cache_paths,
    load_or_generate_dataset,
    load_or_train,
    shipped_model_path,
    shipped_path,
)


def check(c: DynamicsConfig) -> bool:
    """Print, per shipped file ``c`` needs, whether it is there and made by ``c`` (its stored hash); True if all are."""
    p = cache_paths(c, None, None)  # the world of data.world (default: configs/world/default.yaml)
    files = [(shipped_path(p["data_hash"]), lambda f: Transitions.load(f, expected_hash=p["data_hash"]))]
    for m in single_models(c):
        mh = cache_paths(m)["model_hash"]
        files.append((shipped_model_path(mh), lambda f, mh=mh: LearnedDynamics.load(f, expected_hash=mh)))
    ok = True
    for f, load in files:
        if not f.is_file():
            status, ok = "MISSING", False
        else:
            try:
                load(f)
                status = "matches the configuration"
            except DynamicsError as e:
                status, ok = f"STALE ({e})", False
        print(f"shipped {f.name}: {status} ({f})")
    return ok


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        prog="python -m dynamics.shipped", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--check", action="store_true", help="only report whether the shipped files match")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of configs/dynamics/default.yaml (default: none)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base=None):
        cfg: Any = OmegaConf.to_container(compose(config_name="default", overrides=list(args.overrides)), resolve=True)
    c = DynamicsConfig.from_dict(cfg)
    if args.check:
        raise SystemExit(0 if check(c) else 1)
    p = cache_paths(c, None, None)
    singles = single_models(c)
    targets = [shipped_path(p["data_hash"])] + [shipped_model_path(cache_paths(m)["model_hash"]) for m in singles]
    if not p["dataset"].is_file():
        load_or_generate_dataset(c, None, None, True, None, use_shipped=False)
    for m in singles:  # trained here unless cached (a cached checkpoint is the same model: same hash)
        load_or_train(m, use_shipped=False)
    SHIPPED_DIR.mkdir(exist_ok=True)
    for old in [*SHIPPED_DIR.glob("source-*.pt"), *SHIPPED_DIR.glob("model-*.pt")]:
        if old not in targets:
            old.unlink()
            print(f"removed stale {old.name}")
    sources = [p["dataset"]] + [cache_paths(m)["checkpoint"] for m in singles]
    for src, target in zip(sources, targets):
        safeio.atomic_write(target, src.read_bytes())
        print(f"wrote {target} ({target.stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
