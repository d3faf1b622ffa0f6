"""Option groups, each field declared once: the declaration (:func:`option`), its check, the group base.

An option group is a frozen dataclass (:class:`OptionGroup`) whose fields are declared with :func:`option`: the
type and bounds, the allowed names, the default (a value, a rule that depends on the stage rule, or a rule
function, :class:`ByRule` and :class:`DefaultRule`), the help line, the YAML key of the ``solver:`` block, the
command-line flag and the keyword of :func:`~springsim.integrators.make_integrator`. A field left ``None`` was
not given and stands for its declared default. The group's ``__post_init__`` checks every given field against
its declaration (:func:`check_option`), so a group that exists is valid; the run configuration
(:class:`springsim.run.options.SolverConfig`) derives its YAML parser, its flags and the integrator's keywords
from the same declarations.

The groups: :class:`~springsim.integrators._stage.NewtonOptions` (how implicit stages are solved),
:class:`LinearSolveOptions` (the linear solver of implicit integrators, here) and
:class:`springsim.run.options.TimeStepOptions` (the run's steps).

Errors name the field (``jacobian: unknown jacobian mode 'x'; ...``); the run configuration renames them to
``solver.<key>``, the command line to the flag.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field, fields

from ..errors import SceneError, SceneTypeError, check_choice
from ..linsolve import DEFAULT_RTOL

__all__ = ["ByRule", "DefaultRule", "LinearSolveOptions", "OptionGroup", "check_option", "describe_default",
           "describe_int", "option", "renamed"]

#: The kinds of option values (:func:`option`).
KINDS = ("name", "float", "int", "bool", "options")


def describe_int(value: int) -> str:
    """``str(value)``, or its digit count when it is too long to show (Python refuses to print > 4300 digits).

    Parameters
    ----------
    value : int
        The integer.

    Returns
    -------
    str
        The integer, or ``"an integer of about N digits"``.
    """
    if abs(value) < 10**30:
        return str(value)
    return f"an integer of about {int(abs(value).bit_length() * 0.30103) + 1} digits"


class ByRule:
    """A default that depends on the stage rule: one value per rule, or the integrator's own where it has one.

    Parameters
    ----------
    values : dict
        Stage rule -> default; ``None``: the integrator class's attribute ``attr``.
    attr : str, optional
        The integrator class attribute that holds the default of the rules mapped to ``None``.
    """

    def __init__(self, values: dict, attr: str | None = None):
        self.values, self.attr = dict(values), attr

    def value(self, rule: str, integrator: type):
        """The default for stage rule ``rule`` in integrator class ``integrator``.

        Parameters
        ----------
        rule : str
            A stage rule (:data:`~springsim.integrators._stage.STAGE_SOLVERS`).
        integrator : type
            The integrator class.

        Returns
        -------
        object
            The default value.
        """
        v = self.values[rule]
        return getattr(integrator, self.attr) if v is None else v

    def describe(self) -> str:
        """The rule in words for ``--help`` and the docs, from the values (and the registered integrators').

        Returns
        -------
        str
            E.g. ``"50 for minimize stages, 5 for pa2; residual: 5 for implicit_euler, 50 for the others"``.
        """
        own = [f"{format_value(v)} for {rule}{' stages' if not i else ''}"
               for i, (rule, v) in enumerate((r, v) for r, v in self.values.items() if v is not None)]
        text = ", ".join(own)
        for rule, v in self.values.items():
            if v is None:
                from . import INTEGRATORS  # the registry, when the help is rendered

                by = {}
                for name, cls in INTEGRATORS.items():
                    if cls.implicit and cls.converges and rule in cls.stage_solvers:
                        by.setdefault(getattr(cls, self.attr), []).append(name)
                common = max(by, key=lambda k: len(by[k])) if by else None
                parts = [f"{format_value(k)} for {', '.join(names)}" for k, names in by.items() if k != common]
                if common is not None:
                    parts.append(f"{format_value(common)} for the others" if parts else format_value(common))
                text += f"; {rule}: {', '.join(parts)}"
        return text


class DefaultRule:
    """A default computed by a function of the integrator: the function's docstring (first paragraph, one line)
    describes it in ``--help`` and the docs, so the words and the rule sit together.

    Parameters
    ----------
    fn : callable
        ``fn(integrator, options)``: the default for an integrator instance and the group's options resolved so
        far (the fields declared before this one).
    """

    def __init__(self, fn):
        self.fn = fn

    def describe(self) -> str:
        """The rule in words (the function's docstring, first paragraph).

        Returns
        -------
        str
        """
        return " ".join((self.fn.__doc__ or "").strip().split("\n\n")[0].split())


def format_value(value) -> str:
    """A default as ``--help`` shows it: numbers with ``:g``, booleans and names as they are spelt.

    Parameters
    ----------
    value : object
        The default.

    Returns
    -------
    str
    """
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def describe_default(f) -> str | None:
    """The default of the declared field ``f`` in words: its value, its rule, or its ``default_text``; None when
    the field has none to show.

    Parameters
    ----------
    f : dataclasses.Field
        A field declared with :func:`option`.

    Returns
    -------
    str or None
    """
    m = f.metadata
    if m["default_text"] is not None:
        return m["default_text"]
    d = m["default"]
    if isinstance(d, (ByRule, DefaultRule)):
        return d.describe()
    return None if d is None else format_value(d)


def option(default=None, *, kind: str, help: str, yaml: str | bool | None = None, cli: str | None = None,
           cli_aliases: tuple[str, ...] = (), metavar: str | None = None, lo: float | None = None,
           hi: float | None = None, strict: bool = False, hi_strict: bool = False, choices=None,
           what: str | None = None, kwarg: str | None = None, default_text: str | None = None,
           rules: tuple[str, ...] | None = None, needs: str | None = None, filled: bool = False):
    """Declare a field of an option group: the one place of its name, type, bounds, default and spellings.

    Parameters
    ----------
    default
        The value a field left ``None`` stands for: a value, a :class:`ByRule` or a :class:`DefaultRule`
        (``None``: no default; the caller's, or none needed).
    kind : {"name", "float", "int", "bool", "options"}
        A name (checked against ``choices``), a finite number, an integer, a boolean, or options passed through to
        another library (a string, or a mapping of names to scalars).
    help : str
        One line for ``--help`` and the docs, without the default (rendered from ``default``).
    yaml : str or False, optional
        Key in the ``solver:`` block (default: the field name; False: none, a Python-only option).
    cli : str, optional
        Command-line flag of ``springsim run`` (None: YAML and Python only).
    cli_aliases : tuple of str
        Older spellings of the flag, still accepted (``--rtol`` for ``--linear-rtol``).
    metavar : str, optional
        The flag's value in ``--help``.
    lo, hi : float, optional
        Bounds: ``>= lo`` (``> lo`` with ``strict``), ``<= hi`` (``< hi`` with ``hi_strict``).
    strict, hi_strict : bool
        Whether the bounds are strict.
    choices : tuple or callable, optional
        The allowed names of a ``"name"`` field, or a function returning them (a registry, looked up when checked).
    what : str, optional
        What the names are, for the error message (``"jacobian mode"``).
    kwarg : str, optional
        The keyword of :func:`~springsim.integrators.make_integrator` (default: the field name).
    default_text : str, optional
        The default in words where it is not a value or a rule of this group (``"the scene's solver.timestep"``).
    rules : tuple of str, optional
        The stage rules that read a Newton option (``"plain"``: also a plain Newton iteration, linearized implicit
        Euler's); the others ignore it (:meth:`~springsim.integrators._stage.NewtonOptions.read_by`).
    needs : str, optional
        A boolean property of the run configuration (:class:`springsim.run.options.SolverConfig`) without which the
        option has no effect (``"adaptive"``, ``"petsc"``; :meth:`~springsim.run.options.SolverConfig.unused`).
    filled : bool
        The field holds its default when not given (instead of ``None``).

    Returns
    -------
    dataclasses.Field
        The field, its declaration in ``metadata``.

    Raises
    ------
    ValueError
        For an unknown ``kind``.
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    meta = dict(kind=kind, help=help, yaml=yaml, cli=cli, cli_aliases=tuple(cli_aliases), metavar=metavar, lo=lo,
                hi=hi, strict=strict, hi_strict=hi_strict, choices=choices, what=what or kind, kwarg=kwarg,
                default=default, default_text=default_text, rules=None if rules is None else frozenset(rules),
                needs=needs)
    return field(default=default if filled else None, metadata=meta)


def check_option(f, value, where: str):
    """``value`` converted and checked against the declaration of field ``f``; errors name ``where``.

    Parameters
    ----------
    f : dataclasses.Field
        A field declared with :func:`option`.
    value : object
        The value given (None: not given, returned as is).
    where : str
        The path errors name: the parameter, ``solver.<key>`` or the flag.

    Returns
    -------
    object
        The value: numbers as ``float`` or ``int``, booleans as ``bool``, mappings copied.

    Raises
    ------
    SceneTypeError
        For a value of the wrong type.
    SceneError
        For a value out of bounds, not finite, or not one of the allowed names.
    """
    m = f.metadata
    if value is None:
        return None
    kind = m["kind"]
    if kind == "options":  # a string of "-name value" pairs, or a mapping name -> scalar
        if isinstance(value, dict):
            for k, v in value.items():
                if not isinstance(k, str) or not (v is None or isinstance(v, (str, int, float, bool))):
                    raise SceneTypeError(f"{where}.{k}", f"must be a string, number or boolean, got "
                                                        f"{type(v).__name__}")
            return dict(value)
        if not isinstance(value, str):
            raise SceneTypeError(where, f"must be a string or a mapping, got {type(value).__name__} {value!r:.60}")
        return value
    if kind == "name":
        if not isinstance(value, str):
            raise SceneTypeError(where, f"must be a name, got {type(value).__name__} {value!r:.60}")
        choices = m["choices"]
        if choices is not None:
            check_choice(value, choices() if callable(choices) else choices, param=where, what=m["what"])
        return value
    if kind == "bool":
        if not _is_bool(value):
            raise SceneTypeError(where, f"must be a boolean, got {type(value).__name__} {value!r:.60}")
        return bool(value)
    integral = isinstance(value, numbers.Integral)
    if _is_bool(value) or not isinstance(value, numbers.Real) or (kind == "int" and not integral):
        what = "an integer" if kind == "int" else "a number"
        shown = describe_int(int(value)) if integral and not _is_bool(value) else f"{value!r:.60}"
        raise SceneTypeError(where, f"must be {what}, got {type(value).__name__} {shown}")
    if kind == "int":
        value = int(value)
    else:
        try:
            value = float(value)
        except OverflowError:
            value = math.inf
        if not math.isfinite(value):
            raise SceneError(where, f"must be finite, got {value}")
    lo, hi, strict, hi_strict = m["lo"], m["hi"], m["strict"], m["hi_strict"]
    shown = describe_int(value) if kind == "int" else value
    if lo is not None and (value <= lo if strict else value < lo):
        raise SceneError(where, f"must be {'>' if strict else '>='} {lo:g}, got {shown}")
    if hi is not None and (value >= hi if hi_strict else value > hi):
        raise SceneError(where, f"must be {'<' if hi_strict else '<='} "
                                f"{describe_int(hi) if kind == 'int' else format_value(float(hi))}, got {shown}")
    return value


def _is_bool(value) -> bool:
    """Whether ``value`` is a boolean (Python's or NumPy's), not a number."""
    return isinstance(value, bool) or type(value).__name__ == "bool_"


def renamed(error: SceneError, paths: dict) -> SceneError:
    """``error`` with its path renamed by ``paths`` (a field name -> the path of another surface; a path
    ``name.key`` of a mapping field keeps its ``.key``), or ``error`` itself when its path is not in ``paths``.

    Parameters
    ----------
    error : SceneError
        An error of a group's check.
    paths : dict
        Field name (or ``""``: a check of several fields) -> the path to name instead.

    Returns
    -------
    SceneError
        Of the same class as ``error``.
    """
    head, dot, rest = error.path.partition(".")
    if head not in paths:
        return error
    return type(error)(paths[head] + dot + rest if dot else paths[head], error.message)


@dataclass(frozen=True)
class OptionGroup:
    """Base of the frozen option groups: fields declared with :func:`option`, checked on construction.

    A field left ``None`` was not given (it stands for its declared default, :meth:`default`); assigning to a
    field raises :class:`dataclasses.FrozenInstanceError`.

    Raises
    ------
    SceneError
        On construction, naming the field of a value its declaration refuses.
    """

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if value is not None:
                object.__setattr__(self, f.name, check_option(f, value, f.name))
        self.check_combination()

    def check_combination(self) -> None:
        """Checks that involve several fields (none here; groups override it).

        Raises
        ------
        SceneError
            Naming the field at fault (or ``""``: the combination).
        """

    @classmethod
    def declarations(cls) -> dict:
        """The declared fields by name, in declaration order.

        Returns
        -------
        dict
            Field name -> :class:`dataclasses.Field` (its declaration in ``metadata``).
        """
        return {f.name: f for f in fields(cls)}

    @classmethod
    def keyword(cls, name: str) -> str:
        """The :func:`~springsim.integrators.make_integrator` keyword of field ``name``.

        Parameters
        ----------
        name : str
            A field name.

        Returns
        -------
        str
        """
        return cls.declarations()[name].metadata["kwarg"] or name

    @classmethod
    def keywords(cls) -> dict:
        """The keywords of the fields: keyword -> field name.

        Returns
        -------
        dict
        """
        return {cls.keyword(name): name for name in cls.declarations()}

    @classmethod
    def default(cls, name: str):
        """The declared default of field ``name`` (a value, :class:`ByRule`, :class:`DefaultRule`, or None).

        Parameters
        ----------
        name : str
            A field name.

        Returns
        -------
        object
        """
        return cls.declarations()[name].metadata["default"]

    @classmethod
    def from_keywords(cls, options: dict, group=None):
        """The group of ``group``'s fields and the keywords of ``options`` that name its fields, and the rest.

        Parameters
        ----------
        options : dict
            Keyword options (by :meth:`keyword`); None values count as not given.
        group : OptionGroup, optional
            Values given as a group; a keyword may repeat one of its fields only with the same value.

        Returns
        -------
        group : OptionGroup
            Of this class, checked.
        rest : dict
            The options that are not its keywords.

        Raises
        ------
        TypeError
            ``group`` is not an instance of this class.
        SceneError
            A value its declaration refuses, or given twice with different values (naming the keyword).
        """
        if group is not None and not isinstance(group, cls):
            raise TypeError(f"expected a {cls.__name__}, got {type(group).__name__}")
        by_kw = cls.keywords()
        values = {} if group is None else group.given()
        rest = {}
        for kw, value in options.items():
            name = by_kw.get(kw)
            if name is None:
                rest[kw] = value
            elif value is not None:
                if name in values and values[name] != value:
                    raise SceneError(kw, f"given twice: {kw}={value!r:.60} and {cls.__name__}({name}="
                                         f"{values[name]!r:.60})")
                values[name] = value
        try:
            return cls(**values), rest
        except SceneError as e:
            raise renamed(e, {name: kw for kw, name in by_kw.items() if kw != name}) from None

    def given(self) -> dict:
        """The fields that were given (not None), by name.

        Returns
        -------
        dict
        """
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


def _linear_solvers():
    """The registered linear solver names (looked up when a name is checked: solvers registered later count)."""
    from ..linsolve import LINEAR_SOLVERS

    return LINEAR_SOLVERS


@dataclass(frozen=True)
class LinearSolveOptions(OptionGroup):
    """How an implicit integrator solves its linear systems: the solver and its relative tolerance.

    Every field is declared once (:func:`option`); ``None`` stands for the declared default. The integrator
    passes them to its system (:class:`~springsim.system.SerialSystem`; a distributed system takes the
    tolerance as ``linear_rtol`` of :func:`~springsim.distributed.make_distributed`).

    Parameters
    ----------
    linear_solver : str, optional
        A registered linear solver (:data:`springsim.linsolve.LINEAR_SOLVERS`); keyword ``solver`` of
        :func:`~springsim.integrators.make_integrator`, YAML ``linear_solver``, flag ``--solver``. Default
        ``"auto"``.
    linear_rtol : float, optional
        Relative residual tolerance of iterative linear solves, serial and PETSc (``> 0``); YAML ``linear_rtol``,
        flag ``--linear-rtol`` (also ``--rtol``). Default :data:`springsim.linsolve.DEFAULT_RTOL`.

    Raises
    ------
    SceneError
        For an unknown solver or a tolerance that is not a positive finite number, naming the field.
    """

    linear_solver: str | None = option("auto", kind="name", cli="--solver", metavar="NAME", kwarg="solver",
                                       choices=_linear_solvers, what="linear solver",
                                       help="linear solver of implicit integrators")
    linear_rtol: float | None = option(DEFAULT_RTOL, kind="float", cli="--linear-rtol", cli_aliases=("--rtol",),
                                       metavar="R", lo=0.0, strict=True,
                                       help="relative residual tolerance of iterative linear solves, serial and "
                                            "PETSc")
