"""The folders show the data flow: each group (a leaf module or a subpackage of geoscaler/)
imports only from the groups below it, and no module imports another that imports it back
(docs/architecture.md).

A small walk over every module's import statements (function-level ones too; imports under
``if TYPE_CHECKING:`` are for annotations and do not run). The walk itself is checked first on
a made-up package, so that a broken walk cannot pass for a clean tree.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"geoscaler": ROOT / "geoscaler", "geoscaler.app": ROOT / "app"}

LAYERS = [
    ["errors", "protocol", "process", "clock", "color"],
    [""],  # the package itself (geoscaler/__init__.py)
    ["mesh"],
    ["procedural"],
    ["io"],
    ["resize"],
    ["render"],
    ["uv"],
    ["nn"],
    ["optim"],
    ["methods"],
    ["pipeline"],
    ["report"],
    ["batch"],
    ["app", "shaders"],
    ["cli"],
]
"""Bottom to top. A module may import from its own layer's packages only within its own
package (``geoscaler.methods.direct`` from ``geoscaler.methods.registry``), and from any layer
below."""


def module_files(packages: dict[str, Path]) -> dict[str, Path]:
    """Dotted module name -> file, for every ``.py`` file of ``packages``."""
    modules = {}
    for package, folder in packages.items():
        for path in sorted(folder.rglob("*.py")):
            parts = path.relative_to(folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join([package, *parts])] = path
    return modules


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _import_nodes(tree: ast.AST):
    """Every Import/ImportFrom that runs, skipping ``if TYPE_CHECKING:`` bodies."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and _is_type_checking(node):
            stack.extend(node.orelse)
            continue
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node
        stack.extend(ast.iter_child_nodes(node))


def imports_of(name: str, path: Path, modules: dict[str, Path], root: str) -> set[str]:
    """The modules among ``modules`` that module ``name`` (file ``path``) imports."""
    is_package = path.name == "__init__.py"
    found = set()
    for node in _import_nodes(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        else:
            if node.level:
                base = name.split(".")
                base = base if is_package else base[:-1]
                base = base[: len(base) - (node.level - 1)]
                stem = ".".join([*base, node.module] if node.module else base)
            else:
                stem = node.module or ""
            targets = [f"{stem}.{alias.name}" for alias in node.names] + [stem]
            # "from pkg import name" names a module when pkg.name is one, else pkg itself
            targets = [t for t in targets[:-1] if t in modules] or [stem]
        for target in targets:
            while target and target not in modules:
                target = target.rpartition(".")[0]
            if target.startswith(root) and target != name:
                found.add(target)
    return found


def import_graph(packages: dict[str, Path]) -> dict[str, set[str]]:
    modules = module_files(packages)
    root = min(packages, key=len)
    return {name: imports_of(name, path, modules, root) for name, path in modules.items()}


def component(module: str, root: str) -> str:
    """``geoscaler.methods.direct`` -> ``methods``; the root package -> ``""``."""
    rest = module[len(root) :].lstrip(".")
    return rest.split(".")[0]


def layer_of(module: str, root: str, layers: list[list[str]]) -> int:
    part = component(module, root)
    for index, names in enumerate(layers):
        if part in names:
            return index
    raise AssertionError(f"{module}: not in any layer; add {part!r} to LAYERS")


def upward_imports(graph: dict[str, set[str]], root: str, layers: list[list[str]]) -> list[str]:
    """``"a -> b"`` for each import of a module from a higher layer, or from another package
    of its own layer."""
    wrong = []
    for module, targets in sorted(graph.items()):
        mine = layer_of(module, root, layers)
        for target in sorted(targets):
            theirs = layer_of(target, root, layers)
            same_package = component(module, root) == component(target, root)
            if theirs > mine or (theirs == mine and not same_package):
                wrong.append(f"{module} -> {target}")
    return wrong


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for target in graph.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            group = []
            while True:
                member = stack.pop()
                group.append(member)
                if member == node:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


# ----------------------------------------------------------------------------- the walk itself


@pytest.fixture
def toy(tmp_path: Path) -> dict[str, Path]:
    """A made-up package ``toy``: base <- middle <- top, plus one cycle and one upward import."""
    package = tmp_path / "toy"
    (package / "sub").mkdir(parents=True)
    files = {
        "__init__.py": "",
        "base.py": "import os\n",
        "middle.py": "from toy import base\nfrom toy.top import thing  # upward\n",
        "top.py": "from toy.middle import x\nfrom typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from toy import sub\n",
        "sub/__init__.py": "from .a import f\n",
        "sub/a.py": "def f():\n    from toy.sub import b\n",
        "sub/b.py": "from . import a\n",
    }
    for name, text in files.items():
        (package / name).write_text(text)
    return {"toy": package}


def test_the_walk_resolves_absolute_relative_and_function_level_imports(toy):
    graph = import_graph(toy)
    assert graph["toy.middle"] == {"toy.base", "toy.top"}
    assert graph["toy.top"] == {"toy.middle"}  # the TYPE_CHECKING import does not run
    assert graph["toy.sub"] == {"toy.sub.a"}
    assert graph["toy.sub.a"] == {"toy.sub.b"}
    assert graph["toy.sub.b"] == {"toy.sub.a"}


def test_the_walk_finds_cycles_and_upward_imports(toy):
    graph = import_graph(toy)
    assert cycles(graph) == [["toy.middle", "toy.top"], ["toy.sub.a", "toy.sub.b"]]
    layers = [["", "base"], ["middle"], ["top", "sub"]]
    assert upward_imports(graph, "toy", layers) == ["toy.middle -> toy.top"]


# ----------------------------------------------------------------------------- geoscaler


def test_no_import_cycle_among_geoscaler_modules():
    assert cycles(import_graph(PACKAGES)) == []


def test_each_layer_imports_only_from_the_layers_below_it():
    assert upward_imports(import_graph(PACKAGES), "geoscaler", LAYERS) == []


def test_the_method_registry_imports_no_method():
    graph = import_graph(PACKAGES)
    methods = {m for m in graph if m.startswith("geoscaler.methods")}
    assert graph["geoscaler.methods.registry"] & methods == set()


def test_nn_imports_no_renderer_training_loop_or_method():
    graph = import_graph(PACKAGES)
    for module in (m for m in graph if m.startswith("geoscaler.nn")):
        forbidden = {"geoscaler.render.renderer", "geoscaler.render.views", "geoscaler.optim.loop"}
        assert graph[module] & forbidden == set(), module
        assert {component(t, "geoscaler") for t in graph[module]} & {"methods"} == set(), module


def test_no_module_outside_the_clock_reads_the_time():
    """Time is read from the clock object callers pass in (geoscaler.clock): no other module
    calls ``time.perf_counter``, ``time.time`` or ``time.monotonic``."""
    readers = {
        name
        for name, path in module_files(PACKAGES).items()
        if name != "geoscaler.clock"
        and re.search(r"\btime\.(perf_counter|time|monotonic)\(", path.read_text("utf-8"))
    }
    assert readers == set()
