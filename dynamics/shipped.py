"""The default source-world dataset and models, shipped with the package so that a first run need not
simulate or train them.

Generating the default training data takes tens of minutes of simulation on a 2-core CPU and
training the default ensemble's members about a minute each; the files are small (a few thousand
transitions; a few hundred kB per model), so the package carries them under ``dynamics/shipped/``
with the hash of the configuration that made them in their names (``source-<data_hash>.pt``,
``model-<model_hash>.pt``; a model hash covers its data hash). The cache uses a shipped file only
when its hash equals the one the requested configuration needs; a shipped file made by another
configuration (a changed world, solver, data, model or training setting) is reported and never used:
the data is then simulated, the model trained.

    python -m dynamics.shipped            # regenerate the shipped files for the default config
    python -m dynamics.shipped --check    # say whether the shipped files match the default config

``tests/test_dynamics_shipped.py`` regenerates one shard on the CPU and compares it bit for bit,
and (marked ``slow``) retrains a shipped member and compares its predictions.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any, Sequence

log = logging.getLogger(__name__)

SHIPPED_DIR = Path(__file__).resolve().parent / "shipped"


def shipped_path(data_hash: str) -> Path:
    """Where the shipped dataset of a data hash lives (whether or not it exists)."""
    return SHIPPED_DIR / f"source-{data_hash}.pt"


def find_shipped(data_hash: str) -> Path | None:
    """The shipped dataset for ``data_hash``, or None (the shipped files of other hashes are named in the log;
    ``tests/test_dynamics_shipped.py`` fails when the default config's file is missing or stale)."""
    path = shipped_path(data_hash)
    if path.is_file():
        return path
    others = sorted(p.name for p in SHIPPED_DIR.glob("source-*.pt")) if SHIPPED_DIR.is_dir() else []
    if others:
        log.info("the shipped source-world dataset(s) %s were made by another configuration (this one needs "
                    "data hash %s): generating the data instead (run `python -m dynamics.shipped` to refresh "
                    "the shipped file)", others, data_hash)
    return None


def shipped_model_path(model_hash: str) -> Path:
    """Where the shipped checkpoint of a (single-model) model hash lives (whether or not it exists)."""
    return SHIPPED_DIR / f"model-{model_hash}.pt"


def install_shipped_model(checkpoint: Path, model_hash: str) -> bool:
    """Copy the shipped checkpoint for ``model_hash`` to ``checkpoint`` (atomically); False if there is none."""
    import safeio

    from .config import DynamicsError
    from .model import LearnedDynamics

    src = shipped_model_path(model_hash)
    if not src.is_file():
        if SHIPPED_DIR.is_dir() and any(SHIPPED_DIR.glob("model-*.pt")):
            log.info("no shipped dynamics model for model hash %s (the shipped ones were trained with another "
                     "configuration): training it", model_hash)
        return False
    try:  # a damaged or mislabelled file is never copied into the cache
        LearnedDynamics.load(src, expected_hash=model_hash)
    except DynamicsError as e:
        log.warning("the shipped dynamics model %s cannot be used (%s): training it instead", src.name, e)
        return False
    safeio.atomic_write(checkpoint, src.read_bytes())
    log.info("using the shipped dynamics model %s", src.name)
    return True


def install_shipped(dataset: Path, data_hash: str) -> bool:
    """Copy the shipped dataset for ``data_hash`` to ``dataset`` (atomically); False if there is none."""
    import safeio

    src = find_shipped(data_hash)
    if src is None:
        return False
    safeio.atomic_write(dataset, src.read_bytes())
    log.info("using the shipped source-world dataset %s (data hash %s)", src.name, data_hash)
    return True


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m dynamics.shipped", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="only report whether the shipped file matches")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of configs/dynamics/default.yaml (default: none)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    import safeio

    from .config import single_models
    from .train import CONFIG_DIR, _as_config, cache_paths, load_or_generate_dataset, load_or_train

    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base=None):
        cfg: Any = OmegaConf.to_container(compose(config_name="default", overrides=list(args.overrides)), resolve=True)
    c = _as_config(cfg)
    p = cache_paths(c, None, None)  # the world of data.world (default: configs/world/default.yaml)
    singles = single_models(c)
    targets = [shipped_path(p["data_hash"])] + [shipped_model_path(cache_paths(m)["model_hash"]) for m in singles]
    if args.check:
        for f in targets:
            print(f"shipped {f.name}: {'present' if f.is_file() else 'MISSING'} ({f})")
        raise SystemExit(0 if all(f.is_file() for f in targets) else 1)
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
