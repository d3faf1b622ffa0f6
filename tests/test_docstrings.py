"""Every public definition of springsim has a numpydoc docstring whose sections match its signature.

The modules are parsed, not imported. The rule:

* **What is checked.** In every public module of ``springsim/`` (a module is private when a component of its path
  starts with ``_``, a package's ``__init__.py`` excepted): every module-level function and class whose name does
  not start with ``_``, and every public method of such a class (properties included). Also every function and
  class named in the ``__all__`` of a public module, wherever it is defined: ``springsim.integrators.Integrator``
  is public API although it lives in the private ``integrators/_base.py``. Dunder methods, names starting with
  ``_`` and ``typing.overload`` stubs are not checked; constants are documented by their ``#:`` comments.
* **Every checked definition** has a docstring whose first line is its summary.
* **Functions and methods** with parameters (other than ``self``/``cls``) have a ``Parameters`` (or ``Other
  Parameters``) section naming exactly the signature's parameters: none missing, none unknown (a stale name).
  ``*args``/``**kwargs`` may be listed with or without their stars; ``a, b : ndarray`` names two parameters;
  a parameter whose name starts with ``_`` is private and need not be listed (``SystemMatrix._cache``).
  A function whose body has an explicit ``return <value>`` (not ``return``/``return None``, nested functions not
  counted) has a ``Returns`` section; a generator (``yield`` in its body, context managers included) a ``Yields``
  section.
* **Properties** need only the summary line (Sphinx shows them as attributes).
* **Overrides inherit.** A method (or property) that overrides one of a springsim base class with the same signature
  (parameter names, kinds and defaults; annotations aside), where the base method passes this check itself, needs
  nothing: Sphinx's autodoc shows the base docstring when the override has none, and an override's own docstring
  (what this implementation does differently) needs only its summary line (a ``Parameters`` section it has must
  still name the parameters). Base classes outside springsim
  (``logging.Handler``, ``Exception``) give nothing to inherit.
* **Classes** have their constructor's parameters in a ``Parameters`` section of the class docstring (numpydoc;
  ``__init__``'s docstring also counts, as ``autoclass_content = "both"`` renders the two together). The
  constructor is the class's own ``__init__``; for a dataclass (``init=True``) or a ``NamedTuple`` its fields
  (``ClassVar`` and ``field(init=False)`` left out), which may be listed under ``Attributes`` instead, as they
  are both. A class that defines no constructor inherits its base's and its documentation.

Files in :data:`PENDING` are not checked yet; nothing else is left out. Every offender is reported at once, one line
each: ``springsim/path.py:line Qualname: missing Parameters (a, b)``.
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass, field
from pathlib import Path

import springsim

ROOT = Path(springsim.__file__).resolve().parent
PACKAGE = "springsim"

#: Files (paths from the repository root; a path ending in ``/`` is a directory) whose docstrings are completed by
#: someone else and are not checked until then. When a file is complete, its entry goes (test_pending_is_pending).
PENDING: set[str] = set()  # files not checked yet: none

PARAMETER_SECTIONS = ("Parameters", "Other Parameters")
PROPERTY_DECORATORS = {"property", "cached_property", "abstractproperty"}


@dataclass
class Module:
    name: str
    path: Path
    is_package: bool
    tree: ast.Module
    #: Top-level definitions: name -> FunctionDef / ClassDef / assignment.
    defs: dict = field(default_factory=dict)
    #: Imported names: local name -> (module, attribute or None for a module).
    imports: dict = field(default_factory=dict)

    @property
    def rel(self) -> str:
        return self.path.relative_to(ROOT.parent).as_posix()

    @property
    def private(self) -> bool:
        parts = self.path.relative_to(ROOT.parent).parts
        return any(p.startswith("_") for p in parts if p != "__init__.py")

    @property
    def all(self) -> list[str]:
        node = self.defs.get("__all__")
        if isinstance(node, (ast.Assign, ast.AnnAssign)) and isinstance(node.value, (ast.List, ast.Tuple)):
            return [e.value for e in node.value.elts if isinstance(e, ast.Constant) and isinstance(e.value, str)]
        return []


def _resolve_relative(module: Module, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = module.name.split(".") if module.is_package else module.name.split(".")[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _load_modules() -> dict[str, Module]:
    modules = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts = parts[:-1]
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        m = Module(".".join(parts), path, is_package, tree)
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                m.defs[node.name] = node
            elif isinstance(node, ast.Assign):
                for t in node.targets:
                    if isinstance(t, ast.Name):
                        m.defs[t.id] = node
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                m.defs[node.target.id] = node
        for node in ast.walk(tree):  # function-level and TYPE_CHECKING imports re-export too (lazy __getattr__)
            if isinstance(node, ast.ImportFrom):
                source = _resolve_relative(m, node)
                for alias in node.names:
                    m.imports.setdefault(alias.asname or alias.name, (source, alias.name))
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.asname:
                        m.imports.setdefault(alias.asname, (alias.name, None))
        modules[m.name] = m
    return modules


MODULES = _load_modules()


def _find(module: Module, name: str, seen=()) -> tuple[Module, ast.AST] | None:
    """The definition of ``name`` as seen from ``module``, following imports within springsim."""
    if (module.name, name) in seen:
        return None
    seen = seen + ((module.name, name),)
    if name in module.imports:
        source, attr = module.imports[name]
        if attr is not None:
            if f"{source}.{attr}" in MODULES and source + "." + attr != module.name:
                return None  # a submodule, not a definition
            if source in MODULES:
                return _find(MODULES[source], attr, seen)
            return None
    if name in module.defs:
        return module, module.defs[name]
    if module.is_package:  # ``from . import driver; return getattr(driver, name)`` in a lazy __getattr__
        for other in MODULES.values():
            if other.name.startswith(module.name + ".") and name in other.defs:
                return other, other.defs[name]
    return None


def _base_classes(module: Module, cls: ast.ClassDef) -> list[tuple[Module, ast.ClassDef]]:
    """springsim classes among the bases of ``cls``, in the order of the MRO's depth-first walk."""
    out = []
    for base in cls.bases:
        if isinstance(base, ast.Name):
            found = _find(module, base.id)
            if found and isinstance(found[1], ast.ClassDef):
                out.append(found)
                out.extend(_base_classes(*found))
    return out


def _decorator_names(node) -> set[str]:
    names = set()
    for d in node.decorator_list:
        d = d.func if isinstance(d, ast.Call) else d
        if isinstance(d, ast.Name):
            names.add(d.id)
        elif isinstance(d, ast.Attribute):
            names.add(d.attr)
            names.add(ast.unparse(d))
    return names


def _is_property(node) -> bool:
    return bool(_decorator_names(node) & PROPERTY_DECORATORS)


def _is_accessor(node) -> bool:
    """A property's setter or deleter (``@x.setter``): documented by the property."""
    return any(isinstance(d, ast.Attribute) and d.attr in ("setter", "deleter") for d in node.decorator_list)


def _parameters(node, method: bool) -> list[str]:
    a = node.args
    names = [p.arg for p in a.posonlyargs + a.args]
    if method and "staticmethod" not in _decorator_names(node):
        names = names[1:]
    if a.vararg:
        names.append(a.vararg.arg)
    names += [p.arg for p in a.kwonlyargs]
    if a.kwarg:
        names.append(a.kwarg.arg)
    return names


def _signature(node) -> tuple:
    a = node.args
    positional = a.posonlyargs + a.args
    defaults = [None] * (len(positional) - len(a.defaults)) + [ast.unparse(d) for d in a.defaults]
    kw_defaults = [None if d is None else ast.unparse(d) for d in a.kw_defaults]
    return (tuple((p.arg, d) for p, d in zip(positional, defaults)), a.vararg and a.vararg.arg,
            tuple((p.arg, d) for p, d in zip(a.kwonlyargs, kw_defaults)), a.kwarg and a.kwarg.arg,
            "staticmethod" in _decorator_names(node), "classmethod" in _decorator_names(node))


def _own_nodes(node):
    """The nodes of a function's body, not descending into nested functions, classes and lambdas."""
    nested = (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Lambda)
    todo = [n for n in node.body if not isinstance(n, nested)]
    while todo:
        n = todo.pop()
        yield n
        todo.extend(child for child in ast.iter_child_nodes(n) if not isinstance(child, nested))


def _returns_value(node) -> bool:
    return any(isinstance(n, ast.Return) and n.value is not None
               and not (isinstance(n.value, ast.Constant) and n.value.value is None) for n in _own_nodes(node))


def _is_generator(node) -> bool:
    return any(isinstance(n, (ast.Yield, ast.YieldFrom)) for n in _own_nodes(node))


def sections(doc: str) -> dict[str, list[str]]:
    """numpydoc sections of a (cleaned) docstring: title -> the names its entries list (for parameter-like
    sections: the words before `` : `` of each line at the section's indentation, split at commas)."""
    lines = doc.splitlines()
    out: dict[str, list[str]] = {}
    title = indent = None
    for i, line in enumerate(lines):
        if i + 1 < len(lines) and line.strip() and re.fullmatch(r"\s*-{3,}\s*", lines[i + 1]) \
                and len(lines[i + 1].strip()) >= len(line.strip()) // 2:
            title, indent = line.strip(), len(line) - len(line.lstrip())
            out.setdefault(title, [])
            continue
        if title is None or not line.strip() or re.fullmatch(r"\s*-{3,}\s*", line):
            continue
        if len(line) - len(line.lstrip()) == indent:
            head = re.split(r"\s+:\s*|:\s+|:$", line.strip(), maxsplit=1)[0]
            out[title].extend(n.strip() for n in head.split(",") if n.strip())
    return out


@dataclass
class Target:
    module: Module
    node: ast.AST
    qualname: str
    cls: ast.ClassDef | None = None  # the class of a method


def _dataclass_fields(cls: ast.ClassDef) -> list[str] | None:
    """The constructor parameters a dataclass or NamedTuple generates, or None for other classes."""
    generated = False
    for d in cls.decorator_list:
        name = d.func if isinstance(d, ast.Call) else d
        if (isinstance(name, ast.Name) and name.id == "dataclass") or \
                (isinstance(name, ast.Attribute) and name.attr == "dataclass"):
            init = True
            if isinstance(d, ast.Call):
                for kw in d.keywords:
                    if kw.arg == "init" and isinstance(kw.value, ast.Constant):
                        init = bool(kw.value.value)
            generated = init
    if any(isinstance(b, ast.Name) and b.id == "NamedTuple" for b in cls.bases):
        generated = True
    if not generated:
        return None
    fields = []
    for node in cls.body:
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            if "ClassVar" in ast.unparse(node.annotation):
                continue
            v = node.value
            if isinstance(v, ast.Call) and ast.unparse(v.func).endswith("field") and any(
                    kw.arg == "init" and isinstance(kw.value, ast.Constant) and kw.value.value is False
                    for kw in v.keywords):
                continue
            fields.append(node.target.id)
    return fields


def _methods(cls: ast.ClassDef) -> dict[str, ast.AST]:
    return {n.name: n for n in cls.body if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))
            and not _is_accessor(n) and "overload" not in _decorator_names(n)}


def _inherited(target: Target) -> Target | None:
    """The springsim base-class method that ``target`` overrides with the same signature, if it is documented."""
    for base_module, base in _base_classes(target.module, target.cls):
        method = _methods(base).get(target.node.name)
        if method is None:
            continue
        if _signature(method) != _signature(target.node):
            return None
        base_target = Target(base_module, method, f"{base.name}.{method.name}", base)
        return base_target if not problems(base_target) else None
    return None


def problems(target: Target) -> list[str]:
    """What ``target``'s docstring lacks, as phrases (empty when complete)."""
    node = target.node
    doc = ast.get_docstring(node)
    if target.cls is not None and isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) \
            and _inherited(target) is not None:
        # an override of a documented base method or property: autodoc shows the base docstring; a Parameters
        # section of its own must still name the parameters
        found = sections(doc or "")
        if not any(s in found for s in PARAMETER_SECTIONS):
            return []
        return _compare(_parameters(node, method=True), [n for s in PARAMETER_SECTIONS for n in found.get(s, [])],
                        "Parameters")
    if not doc:
        return ["no docstring"]
    if not doc.splitlines()[0].strip():
        return ["no summary line"]
    found = sections(doc)
    out = []
    if isinstance(node, ast.ClassDef):
        fields = _dataclass_fields(node)
        init = _methods(node).get("__init__")
        if init is not None:
            wanted = _parameters(init, method=True)
            init_doc = ast.get_docstring(init)
            listed = found.get("Parameters", []) + found.get("Other Parameters", [])
            if init_doc:
                init_found = sections(init_doc)
                listed += init_found.get("Parameters", []) + init_found.get("Other Parameters", [])
        elif fields is not None:
            wanted = fields
            listed = found.get("Parameters", []) + found.get("Other Parameters", []) + found.get("Attributes", [])
        else:
            return out
        out += _compare(wanted, listed, "Parameters")
        return out
    if target.cls is not None and _is_property(node):
        return out
    wanted = _parameters(node, method=target.cls is not None)
    listed = [n for s in PARAMETER_SECTIONS for n in found.get(s, [])]
    out += _compare(wanted, listed, "Parameters")
    if _is_generator(node):
        if "Yields" not in found:
            out.append("missing Yields")
    elif _returns_value(node) and "Returns" not in found:
        out.append("missing Returns")
    return out


def _compare(wanted: list[str], listed: list[str], section: str) -> list[str]:
    listed = {n.lstrip("*") for n in listed}
    out = []
    missing = [n for n in wanted if n not in listed and not n.startswith("_")]
    unknown = sorted(listed - set(wanted))
    if missing:
        out.append(f"missing {section} ({', '.join(missing)})")
    if unknown:
        out.append(f"{section} lists names not in the signature ({', '.join(unknown)})")
    return out


def targets() -> list[Target]:
    """Every definition the rule covers (PENDING files included), each once, in file order."""
    found: dict[tuple[str, int], Target] = {}

    def add(module: Module, node: ast.AST) -> None:
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            return
        if "overload" in _decorator_names(node):
            return
        found.setdefault((module.rel, node.lineno), Target(module, node, node.name))
        if isinstance(node, ast.ClassDef):
            for name, method in _methods(node).items():
                if not name.startswith("_"):
                    found.setdefault((module.rel, method.lineno), Target(module, method, f"{node.name}.{name}", node))

    for module in MODULES.values():
        if module.private:
            continue
        for name, node in module.defs.items():
            if not name.startswith("_"):
                add(module, node)
    for module in MODULES.values():
        if module.private:
            continue
        for name in module.all:
            definition = _find(module, name)
            if definition is not None:
                add(*definition)
    return [found[k] for k in sorted(found)]


def _pending(rel: str) -> bool:
    return any(rel == p or (p.endswith("/") and rel.startswith(p)) for p in PENDING)


def offenders(include_pending: bool = False) -> list[str]:
    out = []
    for t in targets():
        if not include_pending and _pending(t.module.rel):
            continue
        found = problems(t)
        if found:
            out.append(f"{t.module.rel}:{t.node.lineno} {t.qualname}: {'; '.join(found)}")
    return out


def test_every_public_definition_has_numpydoc_sections():
    bad = offenders()
    assert not bad, f"{len(bad)} public definitions without complete numpydoc sections " \
                    f"(tests/test_docstrings.py gives the rule):\n" + "\n".join(bad)


def test_pending_is_pending():
    """Every PENDING entry exists and still has offenders: a completed file leaves the list."""
    repo = ROOT.parent
    for entry in PENDING:
        assert (repo / entry).exists(), f"PENDING names {entry}, which does not exist"
    bad = offenders(include_pending=True)
    done = [p for p in sorted(PENDING) if not any(line.startswith(p if p.endswith("/") else p + ":") for line in bad)]
    assert not done, f"complete now, remove from PENDING in tests/test_docstrings.py: {', '.join(done)}"


def test_rule_sees_the_sections():
    """The section parser and the checks on a known docstring (the rule's own test)."""
    doc = "Summary.\n\nParameters\n----------\nq, qd : ndarray, shape (N, 3)\n    Positions.\n**kwargs\n" \
          "    Options.\n\nReturns\n-------\nfloat\n    A value.\n"
    assert sections(doc) == {"Parameters": ["q", "qd", "**kwargs"], "Returns": ["float"]}
    tree = ast.parse(f'def f(q, qd, dt, **kwargs):\n    """{doc}"""\n    return 1.0\n')
    module = Module("springsim.example", ROOT / "example.py", False, tree)
    assert problems(Target(module, tree.body[0], "f")) == ["missing Parameters (dt)"]
    tree = ast.parse('def g(a):\n    """Summary.\n\n    Parameters\n    ----------\n    b : int\n        B.\n    """\n'
                     '    if a:\n        return a\n')
    assert problems(Target(module, tree.body[0], "g")) == [
        "missing Parameters (a)", "Parameters lists names not in the signature (b)", "missing Returns"]
    base_doc = "Summary.\n\n        Parameters\n        ----------\n        x : float\n            X.\n        "
    tree = ast.parse(f'class Base:\n    """A base."""\n    def f(self, x):\n        """{base_doc}"""\n\n'
                     'class Sub(Base):\n    """A subclass.\n\n    Attributes\n    ----------\n    y : int\n'
                     '        Y.\n    """\n    def __init__(self, y):\n        self.y = y\n\n'
                     '    def f(self, x):\n        return x\n\n    def g(self, x):\n        """Not inherited."""\n')
    module.tree, module.defs = tree, {n.name: n for n in tree.body}
    base, sub = tree.body
    method = {n.name: n for n in sub.body if isinstance(n, ast.FunctionDef)}
    assert problems(Target(module, sub, "Sub")) == ["missing Parameters (y)"]  # a constructor is no dataclass
    assert problems(Target(module, method["f"], "Sub.f", sub)) == []  # inherits Base.f's docstring
    assert problems(Target(module, method["g"], "Sub.g", sub)) == ["missing Parameters (x)"]


def coverage() -> tuple[int, int]:
    """(complete, total) definitions by the rule, PENDING files included (for reports)."""
    all_targets = targets()
    return sum(not problems(t) for t in all_targets), len(all_targets)


if __name__ == "__main__":  # python tests/test_docstrings.py: the coverage and every offender
    complete, total = coverage()
    print(f"{complete} of {total} public definitions complete")
    print("\n".join(offenders(include_pending=True)))
