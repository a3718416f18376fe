"""The dependency direction of the README: leaves know nothing of the packages that compose them.

Product packages never import the tooling (``benchmarks``) or the tests (``tests``, whose
``tests.doubles`` are stand-ins for tests and benchmarks); the tooling may import anything."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = {"sim", "mde", "planner", "dynamics", "active", "safeio", "task", "configs"}
#: not installed, not product code: run from the repository root
NOT_PRODUCT = {"benchmarks", "tests"}
#: what each package may import of ours (besides itself); never anything of NOT_PRODUCT
ALLOWED = {
    "configs": set(),  # the shipped Hydra configs (data): anyone may locate them through it
    "task": set(),
    "safeio": set(),
    "sim": {"safeio", "task", "configs"},
    "mde": {"safeio"},
    "planner": {"safeio", "task"},
    "dynamics": {"safeio", "task", "sim", "planner", "configs"},
    "active": OURS,
}


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names & (OURS | NOT_PRODUCT)


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_imports_only_what_the_direction_allows(package: str) -> None:
    bad = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        extra = _imports(path) - ALLOWED[package] - {package}
        if extra:
            bad[str(path.relative_to(ROOT))] = sorted(extra)
    assert not bad, f"{package} must not import {bad}"


def test_tooling_and_tests_are_not_installed_packages() -> None:
    tomllib = pytest.importorskip("tomllib")
    from setuptools import find_packages

    include = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]["include"]
    found = set(find_packages(str(ROOT), include=include))
    assert {p.split(".")[0] for p in found} == OURS
