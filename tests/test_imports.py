"""The package's import graph: no cycles (counting imports inside functions, which would hide
them), and no module-level import of the package inside a function."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "skinfit"


def _imports(path: Path):
    """(target module, inside a function) for each relative import of ``path``."""
    tree = ast.parse(path.read_text())
    found = []

    def visit(node, inside):
        for child in ast.iter_child_nodes(node):
            nested = inside or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef))
            if isinstance(child, ast.ImportFrom) and child.level == 1:
                targets = [child.module] if child.module else [alias.name for alias in child.names]
                found.extend((t.split(".")[0], nested) for t in targets)
            visit(child, nested)

    visit(tree, False)
    return found


def _graph(package: Path):
    modules = {p.stem for p in package.glob("*.py")}
    return {p.stem: {t for t, _ in _imports(p) if t in modules and t != p.stem} for p in package.glob("*.py") if p.stem != "__init__"}


def _assert_acyclic(package: Path):
    graph = _graph(package)
    state = {}

    def walk(node, trail):
        state[node] = "open"
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                raise AssertionError("import cycle: " + " -> ".join(trail[trail.index(nxt):] + [nxt]))
            if nxt not in state:
                walk(nxt, trail + [nxt])
        state[node] = "done"

    for module in sorted(graph):
        if module not in state:
            walk(module, [module])


def test_the_package_has_no_import_cycles():
    _assert_acyclic(PACKAGE)


def test_no_module_imports_the_package_inside_a_function():
    hidden = [f"{p.name}: .{t}" for p in PACKAGE.glob("*.py") for t, inside in _imports(p) if inside]
    assert hidden == []


def test_the_cycle_check_finds_a_cycle(tmp_path):
    # the check itself can fail: two modules that import each other, one inside a function
    (tmp_path / "a.py").write_text("from .b import x\n")
    (tmp_path / "b.py").write_text("def f():\n    from .a import y\n")
    try:
        _assert_acyclic(tmp_path)
    except AssertionError as error:
        assert "a -> b -> a" in str(error) or "b -> a -> b" in str(error)
    else:
        raise AssertionError("the cycle went unnoticed")
