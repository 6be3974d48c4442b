"""The package's import graph (an import-linter style "layers" contract, checked on the source):

- the stages are layers, each importing only the ones below it:
  package-root helpers < model < colorimetry < io < segmentation < planning < export < fit < cli;
- no import cycle between modules (counting imports inside functions, which would hide one);
- no import of the package inside a function;
- no import of another subpackage's private module or private name (``from ..model._params``,
  ``from ..fit import _helper``): a stage uses what the one below re-exports in its ``__init__``.
"""

import ast
import warnings
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "skinfit"
LAYERS = ("model", "colorimetry", "io", "segmentation", "planning", "export", "fit", "cli")
# modules of the package root above every stage: the namespace, its deprecation shims, internals
TOP = {"__init__", "__main__", "internal", "_deprecated"}


def _module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _exists(root: Path, dotted: str) -> bool:
    relative = Path(*dotted.split(".")[1:]) if "." in dotted else Path()
    return (root / relative).with_suffix(".py").is_file() or (root / relative / "__init__.py").is_file()


def _imports(root: Path, path: Path):
    """(importing module, imported module, imported names, inside a function) for each relative import."""
    this = _module_name(root, path)
    package = this if path.name == "__init__.py" else this.rpartition(".")[0]
    found = []

    def visit(node, inside):
        for child in ast.iter_child_nodes(node):
            nested = inside or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.ImportFrom) and child.level >= 1:
                base = package.rsplit(".", child.level - 1)[0] if child.level > 1 else package
                target = f"{base}.{child.module}" if child.module else base
                names = [alias.name for alias in child.names]
                submodules = [f"{target}.{n}" for n in names if _exists(root, f"{target}.{n}")]
                for module in submodules:  # `from . import _params`: an import of that module
                    found.append((this, module, [], nested))
                rest = [n for n in names if f"{target}.{n}" not in submodules]
                if rest or not submodules:
                    found.append((this, target, rest, nested))
            visit(child, nested)

    visit(ast.parse(path.read_text()), False)
    return found


def _layer(root: Path, module: str) -> int:
    parts = module.split(".")
    if len(parts) == 1:
        return len(LAYERS) + 1  # the package itself (its __init__)
    if parts[1] in LAYERS:
        return LAYERS.index(parts[1]) + 1
    return len(LAYERS) + 1 if parts[1] in TOP else 0  # 0: the package-root helpers (_validate, ...)


def violations(root: Path) -> list[str]:
    """Every breach of the contract in the package at ``root``."""
    edges = [edge for path in sorted(root.rglob("*.py")) for edge in _imports(root, path)]
    found = []
    for this, target, names, inside in edges:
        if inside:
            found.append(f"{this}: imports {target} inside a function")
        this_layer, target_layer = _layer(root, this), _layer(root, target)
        this_stage, target_stage = this.split(".")[1:2], target.split(".")[1:2]
        if this_stage != target_stage:
            if target_layer > this_layer or (target_layer == this_layer and this_layer not in (0, len(LAYERS) + 1)):
                found.append(f"{this}: imports {target}, a layer above or beside it")
            private = [p for p in target.split(".")[2:] if p.startswith("_")] if target_layer else []
            private_names = [n for n in names if n.startswith("_") and n != "__version__"]
            if target_layer and (private or private_names):
                found.append(f"{this}: imports private {target} {private_names or ''}".rstrip())
    graph: dict[str, set[str]] = {}
    for this, target, _, _ in edges:
        if target != this:
            graph.setdefault(this, set()).add(target)
    state: dict[str, str] = {}

    def walk(node, trail):
        state[node] = "open"
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                found.append("import cycle: " + " -> ".join(trail[trail.index(nxt):] + [nxt]))
            elif nxt not in state:
                walk(nxt, trail + [nxt])
        state[node] = "done"

    for module in sorted(graph):
        if module not in state:
            walk(module, [module])
    return found


def test_the_package_keeps_its_layers():
    assert violations(PACKAGE) == []


def _package(tmp_path, files: dict[str, str]) -> Path:
    root = tmp_path / "skinfit"
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def test_the_contract_finds_a_cycle_an_upward_import_and_a_private_one(tmp_path):
    # the check itself can fail: each breach in a small package of the same shape is reported
    root = _package(tmp_path, {
        "__init__.py": "",
        "_validate.py": "",
        "model/__init__.py": "from ._a import x\n",
        "model/_a.py": "from ._b import y\n",
        "model/_b.py": "def f():\n    from ._a import x\n",
        "fit/__init__.py": "from ._solve import z\n",
        "fit/_solve.py": "from ..model._a import x\nfrom ..model import _hidden\nfrom .._validate import check\n",
        "colorimetry/__init__.py": "from ..fit import z\n",
    })
    found = "\n".join(violations(root))
    assert "import cycle: skinfit.model._a -> skinfit.model._b -> skinfit.model._a" in found
    assert "skinfit.model._b: imports skinfit.model._a inside a function" in found
    assert "skinfit.colorimetry: imports skinfit.fit, a layer above or beside it" in found
    assert "skinfit.fit._solve: imports private skinfit.model._a" in found
    assert "skinfit.fit._solve: imports private skinfit.model ['_hidden']" in found
    assert "_validate" not in found  # the package-root helpers are the bottom layer


def test_the_namespace_is_small_and_every_name_resolves():
    import skinfit

    assert len(skinfit.__all__) <= 30
    for name in skinfit.__all__:
        assert getattr(skinfit, name) is not None
    for stage in LAYERS:
        module = getattr(skinfit, stage)
        for name in module.__all__:
            assert hasattr(module, name), f"skinfit.{stage}.{name}"


def test_the_old_import_paths_still_work_with_a_warning():
    import importlib
    import sys

    import skinfit
    from skinfit import model

    for old, name in [("skinfit.multipole", "slab_response"), ("skinfit.reflectance", "skin_reflectance")]:
        sys.modules.pop(old, None)
        with pytest.warns(DeprecationWarning, match=f"{old} is deprecated .* use skinfit.model"):
            module = importlib.import_module(old)
        assert getattr(module, name) is getattr(model, name)
    with pytest.warns(DeprecationWarning, match="skinfit.stack_transfer is deprecated .* skinfit.model.stack_transfer"):
        assert skinfit.stack_transfer is model.stack_transfer
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert skinfit.model.stack_transfer is model.stack_transfer  # the new path does not warn
    with pytest.raises(AttributeError, match="no attribute 'no_such_name'"):
        skinfit.no_such_name
