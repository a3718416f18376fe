"""The simulator's layers: the engine (``sim/engine/``) knows nothing of the pouring task.

The engine (both solvers, the stencil and colliders they share, the physics, the scene description, motion
profiles, rendering, the solver config and Taichi's set-up) may import itself, ``safeio`` and third-party
packages; the pouring task (worlds, skills, execution, problems, contact prediction, differentiable pours:
the modules of ``sim/`` beside ``engine/``) builds on it, as the project's ``task`` package and its configs do.
Read with ``ast``, so every import counts, those inside functions too. Also here: the size of sim/'s functions
and where its modules import.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SIM = ROOT / "sim"
ENGINE = SIM / "engine"
#: the project's top-level packages other than sim, and the one of them the engine may use
OURS = {"mde", "planner", "dynamics", "active", "safeio", "task", "configs", "benchmarks", "tests"}
ENGINE_MAY_IMPORT = {"safeio"}
#: longest function (lines, decorators and docstring included) in sim/
MAX_FUNCTION_LINES = 80
#: imports inside functions: (file, imported module) -> why it is not at the top of its module
LAZY_IMPORTS = {
    ("sim/engine/render.py", "imageio.v2"): "imageio is heavy and only writes GIFs",
}


def _module(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts)


def _imports(source: str, module: str) -> set[str]:
    """Absolute names of the modules that ``module``'s source imports: relative imports resolved, and for
    ``from m import n`` both m and m.n (n may be a module)."""
    package = module.split(".")[:-1]
    out = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            mod = ".".join(base + ([node.module] if node.module else []))
            out |= {mod} | {f"{mod}.{a.name}" for a in node.names}
    return out


def engine_violations(source: str, module: str) -> list[str]:
    """The imports of an engine module that leave the engine: sim's task modules, the project's other packages."""
    bad = set()
    for name in _imports(source, module):
        top = name.split(".")[0]
        if (top == "sim" and name != "sim" and not name.startswith("sim.engine")) or top in OURS - ENGINE_MAY_IMPORT:
            bad.add(name)
    return sorted(bad)


def _engine_modules() -> list[Path]:
    return sorted(ENGINE.rglob("*.py"))


def test_the_engine_holds_both_solvers_and_what_they_share():
    names = {p.stem for p in _engine_modules()}
    assert {"mpm", "diff_mpm", "stencil", "colliders", "physics", "scene", "config", "backend", "render"} <= names


@pytest.mark.parametrize("path", _engine_modules(), ids=lambda p: p.name)
def test_an_engine_module_imports_no_task_module(path):
    bad = engine_violations(path.read_text(encoding="utf-8"), _module(path))
    assert not bad, (
        f"{path.relative_to(ROOT)} imports {bad}: the engine takes what it needs of the task as "
        "arguments (sim/diff.py builds the differentiable solver from a WorldConfig)"
    )


@pytest.mark.parametrize(
    "source",
    [
        "from ..world import WorldConfig",
        "import sim.skills",
        "from sim import execute",
        "from task import spill",
        "def f():\n    from sim.diff import refine_pours\n",
    ],
)
def test_the_check_sees_a_task_import(source):
    """The rule itself: relative, absolute and function-level imports of the task are all caught, the engine's own
    and third-party ones pass."""
    assert engine_violations(source, "sim.engine.probe")
    assert not engine_violations(
        "from .colliders import Colliders\nimport sim.engine.mpm\nimport numpy\nimport safeio\n", "sim.engine.probe"
    )


def test_no_function_in_sim_is_longer_than_80_lines():
    long = []
    for path in sorted(SIM.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                start = min([node.lineno] + [d.lineno for d in node.decorator_list])
                if node.end_lineno - start + 1 > MAX_FUNCTION_LINES:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({node.end_lineno - start + 1})")
    assert not long, f"split these by phase: {long}"


def test_sim_imports_at_the_top_of_its_modules():
    lazy = set()
    for path in sorted(SIM.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for sub in ast.walk(node):
                    if isinstance(sub, ast.Import):
                        lazy |= {(str(path.relative_to(ROOT)), a.name) for a in sub.names}
                    elif isinstance(sub, ast.ImportFrom):
                        lazy.add((str(path.relative_to(ROOT)), sub.module))
    assert lazy <= set(LAZY_IMPORTS), f"imports inside functions, no reason given: {lazy - set(LAZY_IMPORTS)}"
