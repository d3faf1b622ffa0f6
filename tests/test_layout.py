"""The package layout: the top level holds packages and a short list of modules, and springsim's modules import
each other one way (no import cycles), as do its packages.

Every module of the package is parsed (not imported) and every ``import`` statement in it is an edge of
the intra-package import graph, including those inside functions: a function-level import does not make a
cycle go away, it only moves the failure to the first call. Imports under ``if TYPE_CHECKING:`` are
annotations only and are left out; imports of other packages (numpy, pyamg, petsc4py) are not edges.
Importing ``springsim.a.b`` from outside ``springsim.a`` also runs ``springsim/a/__init__.py``, so it is an
edge to that package too. An import of a name that is no module of the package (a former path such as
``springsim.driver``, which ``springsim._compat`` still serves to users, or a typo) is reported, not dropped.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import springsim

ROOT = Path(springsim.__file__).resolve().parent
PACKAGE = "springsim"

#: The modules allowed at the top level of ``springsim/``: the package's entry points, and the exceptions and the
#: logging that every layer uses. Everything else lives in a package named after its concern (model, forces,
#: assembly, system, linsolve, integrators, run, scene, io, analysis, cli, distributed, _runtime), so that the file
#: list reads as the architecture (README.md, "Architecture").
TOP_LEVEL_MODULES = {"__init__", "__main__", "errors", "progress", "_compat"}


def _modules() -> dict[str, tuple[Path, bool]]:
    """Dotted module name -> (file, whether it is a package's ``__init__``)."""
    out = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts = parts[:-1]
        out[".".join(parts)] = (path, is_package)
    return out


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or \
        (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.AST):
    """The import statements of ``tree`` at any depth, except the bodies of ``if TYPE_CHECKING:``."""
    for child in ast.iter_child_nodes(tree):
        if isinstance(child, ast.If) and _is_type_checking(child):
            for stmt in child.orelse:
                yield from _imports_of(stmt)
            continue
        yield from _imports_of(child)


def _imports_of(node: ast.AST):
    if isinstance(node, (ast.Import, ast.ImportFrom)):
        yield node
    yield from _imports(node)


def import_graph(unresolved: list | None = None) -> dict[str, dict[str, int]]:
    """``{module: {imported module: line of the first such import}}`` over springsim's own modules.

    Imports of springsim names that are no module of the package are appended to ``unresolved`` as
    ``(module, imported name, line)``.
    """
    modules = _modules()
    graph = {}
    for name, (path, is_package) in modules.items():
        package = name if is_package else name.rpartition(".")[0]
        targets: dict[str, int] = {}
        for node in _imports(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            found = []
            if isinstance(node, ast.Import):
                found = [alias.name for alias in node.names]
            else:
                if node.level:
                    base = package.split(".")
                    base = base[:len(base) - (node.level - 1)]
                    base = ".".join(base + ([node.module] if node.module else []))
                else:
                    base = node.module or ""
                # ``from pkg import sub`` imports the submodule ``pkg.sub``; ``from mod import name`` the module
                found = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base
                         for alias in node.names]
            for target in found:
                if target.split(".")[0] != PACKAGE:
                    continue
                if target not in modules and unresolved is not None:
                    unresolved.append((name, target, node.lineno))
                parts = target.split(".")
                # the target's packages that the importer is not inside run their __init__ too
                chain = [".".join(parts[:i]) for i in range(2, len(parts))] + [target]
                for t in chain:
                    if t in modules and t != name and not name.startswith(t + "."):
                        targets.setdefault(t, node.lineno)
        graph[name] = targets
    return graph


def find_cycle(graph: dict[str, dict[str, int]]) -> list[str] | None:
    """One cycle of ``graph`` as ``[a, b, ..., a]``, or None when it is acyclic (iterative depth-first search)."""
    state: dict[str, int] = {}  # 1 on the current path, 2 done
    for start in sorted(graph):
        if state.get(start):
            continue
        path = [start]
        stack = [iter(sorted(graph[start]))]
        state[start] = 1
        while stack:
            nxt = next(stack[-1], None)
            if nxt is None:
                state[path.pop()] = 2
                stack.pop()
                continue
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if not state.get(nxt):
                state[nxt] = 1
                path.append(nxt)
                stack.append(iter(sorted(graph.get(nxt, ()))))
    return None


def test_graph_sees_the_package():
    """The graph holds every module and the edges of a few known imports (module level and in functions)."""
    graph = import_graph()
    assert len(graph) > 50
    assert "springsim.linsolve.amg" in graph["springsim.linsolve.preconditioners"]  # module level
    assert "springsim.linsolve._sa" in graph["springsim.linsolve.amg"]  # inside a method
    assert "springsim.run.driver" in graph["springsim.cli.runner"]  # inside a function
    assert "springsim.distributed" in graph["springsim.cli.runner"]  # the package of a submodule import
    assert "springsim.run.adaptive" not in graph["springsim"]  # only under TYPE_CHECKING


def test_find_cycle():
    assert find_cycle({"a": {"b": 1}, "b": {"c": 1}, "c": {}}) is None
    assert find_cycle({"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b": 1, "c": 1}, "b": {"c": 1}, "c": {"b": 1}}) == ["b", "c", "b"]


def test_no_import_cycles():
    """springsim's modules import each other one way: the import graph, function-level imports included, is
    acyclic."""
    graph = import_graph()
    cycle = find_cycle(graph)
    if cycle is not None:
        steps = [f"{a} (line {graph[a][b]}) -> {b}" for a, b in zip(cycle, cycle[1:])]
        pytest.fail("import cycle: " + "; ".join(steps))


def test_top_level_holds_packages_and_a_few_modules():
    """``springsim/`` holds packages (directories with an ``__init__.py``) and only the modules of
    :data:`TOP_LEVEL_MODULES`: a new module goes into the package of its concern, not beside them."""
    modules = {p.stem for p in ROOT.glob("*.py")}
    extra = sorted(modules - TOP_LEVEL_MODULES)
    assert not extra, f"modules at the top level of springsim/ (move them into the package of their concern): {extra}"
    assert {"__init__", "errors"} <= modules
    for d in ROOT.iterdir():
        if d.is_dir() and d.name != "__pycache__":
            assert (d / "__init__.py").is_file(), f"springsim/{d.name}/ is not a package (no __init__.py)"


def test_every_import_names_a_module_of_the_package():
    """Every springsim import inside the package names one of its modules (or a name in one): no former path of a
    moved module (``springsim.driver``; ``springsim._compat.MOVED``), which the import graph would not see."""
    from springsim._compat import MOVED

    unresolved: list = []
    import_graph(unresolved)
    assert not unresolved, "imports of no module: " + "; ".join(f"{m} line {line}: {t}" for m, t, line in unresolved)
    graph = import_graph()
    assert not [(m, t) for m, targets in graph.items() for t in targets if t in MOVED]


def package_graph(graph: dict[str, dict[str, int]]) -> dict[str, dict[str, str]]:
    """The import graph between the top-level packages and modules of springsim (``springsim.run.driver`` belongs to
    ``run``): ``{package: {imported package: one module-level edge behind it, "a (line n) -> b"}}``."""
    def top(module: str) -> str:
        return module.split(".")[1] if "." in module else module

    out: dict[str, dict[str, str]] = {}
    for module, targets in graph.items():
        for target, line in targets.items():
            a, b = top(module), top(target)
            if a != b:
                out.setdefault(a, {}).setdefault(b, f"{module} (line {line}) -> {target}")
        out.setdefault(top(module), {})
    return out


def test_packages_import_one_way():
    """The packages are layers: none imports, through any of its modules, a package that imports it back. So
    progress and the exceptions, which every layer uses, are top-level modules, and the lower layers never reach up
    into run/, scene/ or io/ (README.md, "Architecture")."""
    packages = package_graph(import_graph())
    assert {"model", "run", "io", "analysis", "_runtime", "forces", "linsolve"} <= set(packages)
    cycle = find_cycle({a: dict.fromkeys(b) for a, b in packages.items()})
    if cycle is not None:
        pytest.fail("package cycle: " + "; ".join(packages[a][b] for a, b in zip(cycle, cycle[1:])))
