"""The house rules of issue 24, checked on the source: no import cycle (counting imports inside
functions and under TYPE_CHECKING), no upward import, no function over 80 lines; and the floors
of docs/ARCHITECTURE.md (issue 69): import-linter's contracts in pyproject.toml hold on the
tree, and fail on a copy of it with an import that runs up a floor."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: import-linter's command, beside this interpreter (the dev extra installs it)
LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")
PACKAGES = ("jointseg", "server", "web")
LAYER = {"jointseg": 0, "server": 1, "web": 2}
MAX_FUNCTION_LINES = 80


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    found: dict[str, Path] = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            found[_module_name(path)] = path
    return found


def _resolve(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    if not node.level:
        return node.module or ""
    base = module.split(".")
    if not is_package:
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def import_graph() -> dict[str, set[str]]:
    """Every module's imports of our own modules, wherever in the file they are written."""
    modules = _modules()
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = _resolve(node, name, path.name == "__init__.py")
                for alias in node.names:
                    sub = f"{base}.{alias.name}"
                    targets.append(sub if sub in modules else base)
            for target in targets:
                while target and target not in modules:
                    target = target.rpartition(".")[0]
                if target and target != name:
                    graph[name].add(target)
    return graph


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    cycles.append(sorted(component))
    return cycles


def test_the_cycle_finder_sees_a_cycle_through_a_function_local_import() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert find_cycles(graph) == [["a", "b", "c"]]
    assert find_cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle() -> None:
    cycles = find_cycles(import_graph())
    assert not cycles, "import cycles: " + "; ".join(" ↔ ".join(c) for c in cycles)


def test_imports_point_down_only() -> None:
    upward = [
        f"{name} → {target}"
        for name, targets in import_graph().items()
        for target in targets
        if LAYER[target.split(".")[0]] > LAYER[name.split(".")[0]]
    ]
    assert not upward, upward


def _long_functions() -> list[str]:
    found = []
    for name, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = (node.end_lineno or node.lineno) - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    found.append(f"{name}.{node.name} ({lines} lines)")
    return found


def test_no_function_over_80_lines() -> None:
    assert not _long_functions()


@pytest.mark.parametrize("package", PACKAGES)
def test_every_package_is_on_the_architecture_map(package: str) -> None:
    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    inits = (ROOT / package).rglob("__init__.py")
    subpackages = sorted(_module_name(p.parent) for p in inits if p.parent != ROOT / package)
    missing = [s for s in subpackages if f"{s.split('.', 1)[1].replace('.', '/')}/" not in text]
    assert not missing, f"ARCHITECTURE.md does not name {missing}"


def _lint_imports(root: Path) -> subprocess.CompletedProcess[str]:
    """import-linter's contracts (``root``'s pyproject.toml) checked on the packages under
    ``root``: they come first on the path, before the checkout's editable install."""
    if not LINT_IMPORTS.is_file():
        pytest.fail(f"no {LINT_IMPORTS}: pip install -e '.[dev]' installs import-linter")
    env = {**os.environ, "PYTHONPATH": str(root)}
    command = [str(LINT_IMPORTS), "--no-cache", "--no-logo"]
    return subprocess.run(command, cwd=root, env=env, capture_output=True, text=True, timeout=300)


def test_the_floors_of_the_architecture_map_hold() -> None:
    done = _lint_imports(ROOT)
    assert done.returncode == 0, f"lint-imports:\n{done.stdout[-6000:]}{done.stderr[-2000:]}"
    assert "0 broken" in done.stdout and "BROKEN" not in done.stdout


#: Imports that run against a floor, each written into a copy of the tree (inside a function,
#: where grimp sees it too), and what lint-imports says of each.
UPWARD = (
    ("jointseg/io/units.py", "jointseg.pipeline"),
    ("jointseg/network/judge.py", "jointseg.frame.judge"),
    ("server/schemas.py", "server.state.models"),
    ("jointseg/scan.py", "server.settings"),
    ("jointseg/network/randlanet/predict.py", "jointseg.network.checkpoint"),
)
SAID = (
    "jointseg.io is not allowed to import jointseg.pipeline",
    "jointseg.network is not allowed to import jointseg.frame",
    "server.schemas is not allowed to import server.state",
    "jointseg is not allowed to import server",
    # the checkpoint module above RandLA-Net's folder, which imports it back
    "No cycles are allowed in jointseg.network",
)


def test_the_floor_contracts_fail_on_an_import_up_a_floor(tmp_path: Path) -> None:
    for package in PACKAGES:
        shutil.copytree(ROOT / package, tmp_path / package, ignore=_not_python)
    shutil.copy2(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    for path, target in UPWARD:
        with (tmp_path / path).open("a") as fh:
            fh.write(f"\n\ndef _upward() -> None:\n    import {target}  # noqa: F401\n")
    done = _lint_imports(tmp_path)
    assert done.returncode != 0, done.stdout[-4000:]
    for said in SAID:
        assert said in done.stdout, f"{said!r} not in:\n{done.stdout[-6000:]}"


def _not_python(folder: str, names: list[str]) -> list[str]:
    """What a copy of the packages for the import graph leaves out: data files (the bundled
    weights), caches."""
    return [
        n
        for n in names
        if n == "__pycache__" or (Path(folder, n).is_file() and not n.endswith(".py"))
    ]
