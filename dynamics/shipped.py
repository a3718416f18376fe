"""The default source-world dataset, shipped with the package so that a first run need not simulate it.

Generating the default training data takes minutes of simulation on a 2-core CPU; the file is small
(a few thousand transitions), so the package carries it under ``dynamics/shipped/`` with the hash
of the configuration that made it in its name (``source-<data_hash>.pt``). The cache uses a shipped
file only when its hash equals the one the requested configuration needs; a shipped file made by
another configuration (a changed world, solver or data setting) is reported and never used.

    python -m dynamics.shipped            # regenerate the shipped file for the default config
    python -m dynamics.shipped --check    # say whether the shipped file matches the default config

``tests/test_dynamics_shipped.py`` regenerates one shard on the CPU and compares it bit for bit.
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

    from .train import CONFIG_DIR, _as_config, cache_paths, load_or_generate_dataset

    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base=None):
        cfg: Any = OmegaConf.to_container(compose(config_name="default", overrides=list(args.overrides)), resolve=True)
    c = _as_config(cfg)
    p = cache_paths(c, None, None)  # the world of data.world (default: configs/world/default.yaml)
    target = shipped_path(p["data_hash"])
    if args.check:
        ok = target.is_file()
        print(f"shipped dataset for data hash {p['data_hash']}: {'present' if ok else 'MISSING'} ({target})")
        raise SystemExit(0 if ok else 1)
    if not p["dataset"].is_file():
        load_or_generate_dataset(c, None, None, True, None, use_shipped=False)
    SHIPPED_DIR.mkdir(exist_ok=True)
    for old in SHIPPED_DIR.glob("source-*.pt"):
        if old != target:
            old.unlink()
            print(f"removed stale {old.name}")
    safeio.atomic_write(target, p["dataset"].read_bytes())
    print(f"wrote {target} ({target.stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
