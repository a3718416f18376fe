"""The dependency direction of the README: leaves know nothing of the packages that compose them."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = {"sim", "mde", "planner", "dynamics", "active", "safeio", "task"}
#: what each package may import of ours (besides itself)
ALLOWED = {
    "task": set(),
    "safeio": set(),
    "sim": {"safeio", "task"},
    "mde": {"safeio"},
    "planner": {"safeio", "task"},
    "dynamics": {"safeio", "task", "sim", "planner"},
    "active": OURS,
}

#: tooling that composes packages but still lives inside one (to move out of the product packages)
TOOLING = {"planner/bench.py", "planner/bench_pool.py"}


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names & OURS


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_imports_only_what_the_direction_allows(package: str) -> None:
    bad = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        if str(path.relative_to(ROOT)) in TOOLING:
            continue
        extra = _imports(path) - ALLOWED[package] - {package}
        if extra:
            bad[str(path.relative_to(ROOT))] = sorted(extra)
    assert not bad, f"{package} must not import {bad}"
