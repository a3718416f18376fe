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
    "mde": {"safeio", "task"},
    "planner": {"safeio", "task"},
    "dynamics": {"safeio", "task", "sim", "configs"},
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


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _module_imports(path: Path, known: set[str]) -> set[str]:
    """The modules of ours that ``path`` imports anywhere (inside functions too; not under TYPE_CHECKING),
    resolved to the most specific known module (``from sim.skills import pour`` -> ``sim.skills``)."""
    me = _module_name(path)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    found: set[str] = set()

    def resolve(name: str) -> None:
        while name and name not in known:
            name = name.rpartition(".")[0]
        if name and name != me:
            found.add(name)

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            for a in node.names:
                resolve(a.name)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(
                    package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else [])
                )
            for a in node.names:  # ``from pkg import module`` names a module
                resolve(f"{base}.{a.name}" if f"{base}.{a.name}" in known else base)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(ast.parse(path.read_text(encoding="utf-8")))
    return found


def test_no_import_cycle_between_modules() -> None:
    """No two modules of the product reach each other through imports (anywhere in a module, inside functions
    too): a cycle hidden by an import inside a function is still one idea split across two modules."""
    import networkx as nx

    paths = [p for pkg in sorted(OURS) for p in sorted((ROOT / pkg).rglob("*.py"))]
    known = {_module_name(p) for p in paths}
    graph = nx.DiGraph()
    for p in paths:
        me = _module_name(p)
        graph.add_node(me)
        for dep in _module_imports(p, known):
            if not (p.name == "__init__.py" and dep.startswith(me + ".")):  # a package re-exporting its modules
                graph.add_edge(me, dep)
    cycles = [sorted(c) for c in nx.strongly_connected_components(graph) if len(c) > 1]
    assert not cycles, f"module import cycles: {cycles}"
