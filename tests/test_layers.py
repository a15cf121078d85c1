"""The package layers hold: `common` <- `sampler` <- `actors` <- `learner` (each imports only the
layers before it), `deploy/` and `tests/` sit outside and nothing imports them, and no import
circle joins two modules. Every import counts, at module level or inside a function, and so do
imports made only for type checking: each shows a dependency. docs/ARCHITECTURE.md's package
table says the same as `LAYERS` (its "depends on" column)."""

from __future__ import annotations

import ast
import graphlib
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("common", "sampler", "actors", "learner")
"""Lowest first: a module may import its own layer and those before it."""
OUTSIDE = ("deploy", "tests")
"""May import every layer; no layer may import them."""


def _modules() -> dict[str, Path]:
    found = {}
    for pkg in LAYERS + OUTSIDE:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


MODULES = _modules()


def _owner(name: str) -> str | None:
    """The project module that `name` (a module or a name inside one) lives in."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imports(name: str, path: Path) -> set[str]:
    """The project modules `name` imports anywhere in its file, without its own ancestor packages
    (Python runs a package's `__init__` before any of its modules, so that is no circle)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in MODULES else base for alias in node.names]
        else:
            continue
        for target in targets:
            owner = _owner(target)
            if owner and owner != name and not name.startswith(owner + "."):
                found.add(owner)
    return found


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def _layer(name: str) -> str:
    return name.split(".")[0]


def test_no_import_runs_up_the_layers() -> None:
    up = []
    for name, targets in GRAPH.items():
        if _layer(name) in OUTSIDE:
            continue
        for target in sorted(targets):
            if _layer(target) in OUTSIDE or LAYERS.index(_layer(target)) > LAYERS.index(_layer(name)):
                up.append(f"{name} -> {target}")
    assert not up, "imports from a lower layer to a higher one:\n" + "\n".join(up)


def test_no_import_cycle() -> None:
    try:
        tuple(graphlib.TopologicalSorter(GRAPH).static_order())
    except graphlib.CycleError as exc:
        raise AssertionError(f"import cycle: {' -> '.join(exc.args[1])}") from None


def test_the_architecture_table_says_the_same() -> None:
    """Each package's row in docs/ARCHITECTURE.md's table names exactly the layers its modules import."""
    text = (ROOT / "docs/ARCHITECTURE.md").read_text()
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| `(\w+)/` \| ([^|]*) \|", text, flags=re.M)}
    for package in LAYERS + ("deploy",):
        assert package in rows, f"docs/ARCHITECTURE.md's package table has no row for `{package}/`"
        imported = {_layer(t) for name, targets in GRAPH.items() if _layer(name) == package for t in targets} - {package}
        named = set(re.findall(r"`(\w+)`", rows[package]))
        assert named == imported, f"`{package}/` imports {sorted(imported) or 'nothing of the project'}; the table says {rows[package]!r}"


def test_the_reader_sees_imports_inside_functions() -> None:
    """A check of the reader itself: a known import inside a function is found."""
    assert "learner.train" in GRAPH["learner.main"], sorted(GRAPH["learner.main"])




def _function_imports(path: Path) -> list[int]:
    """Line numbers of the import statements inside a function (or lambda) of `path`."""
    found = []

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if in_function and isinstance(child, (ast.Import, ast.ImportFrom)):
                found.append(child.lineno)
            visit(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    visit(ast.parse(path.read_text(), str(path)), False)
    return found


def test_imports_inside_functions_say_why() -> None:
    """An import inside a function stays there only for a reason (a heavy dependency used on one
    path, the start-up time of a command's --help, an import order, an optional part) and says
    which in a `# lazy: <reason>` comment on its line or the line above; every other import
    belongs at the top of its module."""
    unexplained = []
    for name, path in MODULES.items():
        rel = path.relative_to(ROOT).as_posix()
        if _layer(name) in OUTSIDE:
            continue
        lines = path.read_text().splitlines()
        for lineno in _function_imports(path):
            here, above = lines[lineno - 1], lines[lineno - 2] if lineno > 1 else ""
            if "# lazy:" not in here and not above.strip().startswith("# lazy:"):
                unexplained.append(f"{rel}:{lineno}: {here.strip()}")
    assert not unexplained, ("imports inside functions without a `# lazy: <reason>` comment (move them to the "
                             "top of the module, or say why they wait):\n" + "\n".join(unexplained))
