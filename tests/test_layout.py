"""The package's layout keeps the promises docs/layout.md makes: rooms imported one way, no import
cycle between any modules (function-level imports included), no module over 500 lines and no
function over 80 (issue 45's limits), read from the source with `ast`, not from the package's
own code."""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "surestep_ocp"
# docs/layout.md: each room imports only from the rooms before it
ROOMS = ["model", "problem", "output", "ocp", "solvers", "methods", "evaluation", "ros"]
MAX_MODULE_LINES, MAX_FUNCTION_LINES = 500, 80


def _modules() -> dict[str, Path]:
    out = {}
    for f in PKG.rglob("*.py"):
        parts = list(f.relative_to(PKG.parent).with_suffix("").parts)
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> set[str]:
    """The package's modules `name` imports anywhere in its file (top or inside a function)."""
    pkg = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[:len(pkg) - (node.level - 1)]
                mod = ".".join([*base, *([node.module] if node.module else [])])
            else:
                mod = node.module or ""
            found.update(t for t in [mod] + [f"{mod}.{a.name}" for a in node.names]
                         if t in MODULES)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name in MODULES)
    # a module's own package (its __init__) is not a dependency cycle
    return {t for t in found if t != name and not name.startswith(t + ".")}


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def test_the_package_is_found():
    assert len(MODULES) > 100 and "surestep_ocp.methods.planner" in MODULES


def test_rooms_import_one_way():
    bad = []
    for name, targets in GRAPH.items():
        room = name.split(".")[1] if name.count(".") >= 2 else None
        for t in targets:
            to = t.split(".")[1] if t.count(".") >= 1 else None
            if room in ROOMS and to in ROOMS and ROOMS.index(to) > ROOMS.index(room):
                bad.append(f"{name} -> {t}")
    assert not bad, bad


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index, low, stack, on, cycles = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return cycles


def test_no_import_cycle():
    assert not _cycles(GRAPH), _cycles(GRAPH)


def test_no_module_over_the_limit():
    long = {n: p.read_text().count("\n") for n, p in MODULES.items()}
    assert not {n: k for n, k in long.items() if k > MAX_MODULE_LINES}


def test_no_function_over_the_limit():
    long = []
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    long.append(f"{name}.{node.name}: {lines}")
    assert not long, long


# the lazy entry points (the command line, the API, the package): their imports wait for a command
ENTRY_POINTS = {"surestep_ocp", "surestep_ocp.cli", "surestep_ocp.api"}
MAX_LOCAL_IMPORTS = 14  # issue 45: fewer than 15, each an optional or slow dependency loaded on use


def _local_imports(source: str) -> list[int]:
    """The lines of the import statements inside functions."""
    return [node.lineno for fn in ast.walk(ast.parse(source))
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef))
            for node in ast.walk(fn) if isinstance(node, (ast.Import, ast.ImportFrom))]


def test_few_imports_inside_functions():
    found = [f"{name}:{line}" for name, path in MODULES.items() if name not in ENTRY_POINTS
             for line in _local_imports(path.read_text())]
    assert len(found) <= MAX_LOCAL_IMPORTS, found
    # (counted as written: one in a function, one in a method, none at the top)
    assert _local_imports("import a\ndef f():\n    import b\nclass C:\n    def g(self):\n"
                          "        from . import c\n") == [3, 6]


def test_the_checks_catch_a_cycle_and_a_long_function(tmp_path):
    """The checks above on a made-up package: a two-module cycle inside a function and a function
    of 81 lines are found (the tests can fail)."""
    a = "def f():\n    from .b import g\n" + "    x = 1\n" * 79
    tree = ast.parse(a)
    fn = tree.body[0]
    assert fn.end_lineno - fn.lineno + 1 == 81 > MAX_FUNCTION_LINES
    pkg = tmp_path / "surestep_ocp" / "demo"
    pkg.mkdir(parents=True)
    (pkg / "a.py").write_text(a)
    (pkg / "b.py").write_text("from .a import f\n\ndef g():\n    return f\n")
    MODULES["surestep_ocp.demo.a"], MODULES["surestep_ocp.demo.b"] = pkg / "a.py", pkg / "b.py"
    try:
        assert _imports("surestep_ocp.demo.a", pkg / "a.py") == {"surestep_ocp.demo.b"}
        assert _imports("surestep_ocp.demo.b", pkg / "b.py") == {"surestep_ocp.demo.a"}
        graph = {n: _imports(n, MODULES[n]) for n in ("surestep_ocp.demo.a", "surestep_ocp.demo.b")}
        assert _cycles(graph) == [["surestep_ocp.demo.a", "surestep_ocp.demo.b"]]
    finally:
        del MODULES["surestep_ocp.demo.a"], MODULES["surestep_ocp.demo.b"]
