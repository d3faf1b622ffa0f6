"""Run options, declared once: :class:`SolverConfig`.

Every option a run takes (the YAML ``solver:`` block, the command-line flags of ``springsim run``,
the keywords of :func:`springsim.integrators.make_integrator` and the drivers) is one field of
:class:`SolverConfig`, declared with :func:`option`: its type and bounds, default, help text, YAML
key, command-line flag and where it goes (the integrator, its linear solver, or the driver). The
YAML parser (:meth:`SolverConfig.from_yaml`), the validation (:meth:`SolverConfig.validate`), the
command-line flags (:meth:`SolverConfig.add_arguments`) and the keyword options
(:meth:`SolverConfig.integrator_options`) are all derived from the declarations, so adding an
option is one field here.

Errors: the Python API raises :class:`~springsim.errors.SceneError` (a ``ValueError``) whose path is
the parameter (``jacobian: must be one of ...``); :class:`SolverConfig` reports the YAML field path
(``solver.jacobian``), and the command line its flag.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass, field, fields, replace

from ..errors import SceneError, SceneTypeError, check_choice

__all__ = ["ADAPTIVE_H_MIN", "BACKENDS", "MAX_STEPS", "DEFAULT_STEPS", "SolverConfig", "option", "describe_int", "steps_for_duration"]

#: Largest number of steps a run may ask for (a guard against overflowing step counts).
MAX_STEPS = 10**12

#: Backends of a run: ``serial`` (one process), ``petsc`` (:mod:`springsim.distributed`, under ``mpiexec``).
BACKENDS = ("serial", "petsc")

#: Run length used when neither the scene nor the caller gives one.
DEFAULT_STEPS = 100

#: Smallest step of adaptive runs (the ``h_min`` default of :func:`springsim.run.adaptive.simulate_adaptive`):
#: the lower bound of ``max_step``.
ADAPTIVE_H_MIN = 1e-7


def describe_int(value: int) -> str:
    """``str(value)``, or its digit count when it is too long to show (Python refuses to print > 4300 digits)."""
    if abs(value) < 10**30:
        return str(value)
    return f"an integer of about {int(abs(value).bit_length() * 0.30103) + 1} digits"


def steps_for_duration(duration: float, dt: float) -> int:
    """Steps of size ``dt`` that cover ``duration`` [s]: ``ceil(duration / dt)`` (a relative 1e-9 slack absorbs
    rounding, so 1.0 / 0.01 is 100 steps); at least 1 for a positive duration, 0 for 0.

    Raises
    ------
    ValueError
        When that exceeds :data:`MAX_STEPS` (or overflows).
    """
    try:
        ratio = float(duration) / float(dt)
    except (OverflowError, ZeroDivisionError):
        ratio = math.inf
    if not ratio <= MAX_STEPS:
        raise ValueError(f"a duration of {duration:g} s in steps of {dt:g} s needs more than {MAX_STEPS:.0e} steps")
    return max(int(math.ceil(ratio - 1e-9 * max(ratio, 1.0))), 1 if duration > 0 else 0)


def option(default=None, *, kind: str, help: str, yaml: str | None = None, cli: str | None = None,
           cli_aliases: tuple[str, ...] = (), metavar: str | None = None, lo: float | None = None,
           hi: float | None = None, strict: bool = False, to: str = "run", kwarg: str | None = None):
    """Declare a field of :class:`SolverConfig`.

    Parameters
    ----------
    default
        Value when not given (None: the integrator's or solver's own default).
    kind : {"name", "float", "int", "options"}
        A registered name (a string checked by the factory), a finite number, an integer, or options passed
        through to another library (a string, or a mapping of names to scalars).
    help : str
        One line for ``--help`` and the docs.
    yaml : str, optional
        Key in the ``solver:`` block (default: the field name).
    cli : str, optional
        Command-line flag of ``springsim run`` (None: YAML and Python only).
    cli_aliases : tuple of str
        Older spellings of the flag, still accepted (``--rtol`` for ``--linear-rtol``).
    lo, hi, strict
        Bounds: ``>= lo`` (``> lo`` with ``strict``), ``<= hi``.
    to : {"integrator", "solver", "run"}
        Where the value goes: a keyword of :func:`~springsim.integrators.make_integrator`, an option of its
        linear solver, or the driver.
    kwarg : str, optional
        The keyword name there (default: the field name).
    """
    meta = dict(kind=kind, help=help, yaml=yaml, cli=cli, cli_aliases=tuple(cli_aliases), metavar=metavar, lo=lo,
                hi=hi, strict=strict, to=to, kwarg=kwarg)
    return field(default=default, metadata=meta)


def _check(f, value, where: str):
    """``value`` converted and checked against field ``f``'s declaration; errors name ``where``."""
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
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (kind == "int" and not isinstance(value, int)):
        what = "an integer" if kind == "int" else "a number"
        shown = describe_int(value) if isinstance(value, int) and not isinstance(value, bool) else f"{value!r:.60}"
        raise SceneTypeError(where, f"must be {what}, got {type(value).__name__} {shown}")
    if kind == "float":
        try:
            value = float(value)
        except OverflowError:
            value = math.inf
        if not math.isfinite(value):
            raise SceneError(where, f"must be finite, got {value}")
    lo, hi, strict = m["lo"], m["hi"], m["strict"]
    if lo is not None and (value <= lo if strict else value < lo):
        shown = describe_int(value) if kind == "int" else value
        raise SceneError(where, f"must be {'>' if strict else '>='} {lo:g}, got {shown}")
    if hi is not None and value > hi:
        raise SceneError(where, f"must be <= {describe_int(hi) if kind == 'int' else hi}, got "
                                f"{describe_int(value) if kind == 'int' else value}")
    return value


@dataclass
class SolverConfig:
    """How to run a scene: the ``solver:`` block of a YAML scene, the flags of ``springsim run``.

    Every field is declared with :func:`option` (see the module docstring); ``None`` means the
    default of the integrator, the linear solver or the driver.
    """

    integrator: str = option("implicit_euler", kind="name", yaml="type", cli="--integrator", metavar="NAME",
                             help="time integrator (default: the scene's solver.type)", to="run")
    dt: float = option(None, kind="float", yaml="timestep", cli="--dt", metavar="H", lo=0.0, strict=True,
                       help="time step [s] (default: the scene's solver.timestep); with adaptive stepping the first step "
                            "and the frame spacing")
    steps: int | None = option(None, kind="int", cli="--steps", metavar="N", lo=0, hi=MAX_STEPS,
                               help="number of steps (default: from duration, else 100)")
    duration: float | None = option(None, kind="float", cli="--duration", metavar="T", lo=0.0,
                                    help="simulated time [s] (steps = ceil(T/dt)); give steps or duration")
    linear_solver: str | None = option(None, kind="name", cli="--solver", metavar="NAME", to="integrator",
                                       kwarg="solver", help="linear solver of implicit integrators (default: auto)")
    jacobian: str | None = option(None, kind="name", cli="--jacobian", metavar="MODE", to="integrator",
                                  help="Jacobian mode (default: mixed for minimize stages, exact for pa2, else exact "
                                       "where the solver takes any matrix and spd where it needs SPD matrices)")
    linear_rtol: float | None = option(None, kind="float", cli="--linear-rtol", cli_aliases=("--rtol",),
                                       metavar="R", lo=0.0, strict=True, to="solver", kwarg="rtol",
                                       help="relative residual tolerance of iterative linear solves, serial and "
                                            "PETSc (default: springsim.linsolve.DEFAULT_RTOL)")
    stage_solver: str | None = option(None, kind="name", cli="--stage-solver", metavar="RULE", to="integrator",
                                      help="how implicit stages are solved: minimize (the incremental potential, "
                                           "projected Newton and a line search on it; the default), residual "
                                           "(Newton with a line search on the residual) or pa2 (the course's rule)")
    force_rtol: float | None = option(None, kind="float", cli="--force-rtol", metavar="R", lo=0.0, strict=True,
                                      to="integrator",
                                      help="minimize stages: stop when the force imbalance |grad E| is below this "
                                           "fraction of the stage's force scale (default 1e-5)")
    force_atol: float | None = option(None, kind="float", cli="--force-atol", metavar="F", lo=0.0,
                                      to="integrator",
                                      help="minimize stages: absolute force imbalance tolerance [N] (default 0)")
    newton_tol: float | None = option(None, kind="float", cli="--newton-tol", metavar="TOL", lo=0.0, strict=True,
                                      to="integrator", help="residual and pa2 stages: Newton update tolerance on "
                                                            "|dv| [m/s] (default 1e-5)")
    newton_maxiter: int | None = option(None, kind="int", cli="--newton-maxiter", metavar="N", lo=1, hi=10**6,
                                        to="integrator",
                                        help="Newton iteration limit of a stage (default 50 for minimize stages, 5 "
                                             "for pa2; residual: 5 for implicit_euler, 50 for the others)")
    residual_rtol: float | None = option(None, kind="float", cli="--residual-rtol", metavar="R", lo=0.0,
                                         strict=True, to="integrator",
                                         help="Newton residual tolerance, relative to the balanced terms "
                                              "(default 1e-3)")
    forcing: str | None = option(None, kind="name", cli="--forcing", metavar="RULE", to="integrator",
                                 help="relative tolerance of Newton's linear solves: fixed (the solver's rtol, default) "
                                      "or eisenstat-walker (loose far from the root, tightening as Newton converges)")
    time_rtol: float | None = option(None, kind="float", cli="--time-rtol", metavar="R", lo=0.0, strict=True,
                                     help="adaptive time stepping (bdf2, tr_bdf2, energy_momentum): relative local "
                                          "error tolerance (default: fixed steps; with only time_atol, equal to it)")
    time_atol: float | None = option(None, kind="float", cli="--time-atol", metavar="A", lo=0.0, strict=True,
                                     help="adaptive time stepping: absolute local error tolerance [m, m/s] (default: "
                                          "time_rtol)")
    max_step: float | None = option(None, kind="float", cli="--max-step", metavar="H", lo=ADAPTIVE_H_MIN,
                                    help="adaptive time stepping: largest step [s], at least 1e-7 s (default a tenth "
                                         "of the run)")

    backend: str | None = option(None, kind="name", cli="--backend", metavar="NAME",
                                 help="serial (default) or petsc: distributed assembly and solves on PETSc, run under "
                                      "mpiexec (docs/distributed.md)")
    partitioner: str | None = option(None, kind="name", cli="--partitioner", metavar="NAME",
                                     help="petsc backend: how the particles are split over the ranks: contiguous "
                                          "(default; blocks of the serial numbering) or a graph partitioner of "
                                          "PETSc (ptscotch, parmetis)")
    petsc_options: str | dict | None = option(None, kind="options", cli="--petsc-options", metavar="OPTS",
                                              help="PETSc options of the petsc backend, e.g. '-ksp_type gmres "
                                                   "-pc_gamg_threshold 0.02' (in YAML also a mapping; PETSC_OPTIONS "
                                                   "applies too)")

    def __post_init__(self):
        self.validate()

    # -- declarations --------------------------------------------------------------------------------
    @classmethod
    def yaml_key(cls, name: str) -> str:
        """The ``solver:`` key of field ``name``."""
        return cls._fields()[name].metadata["yaml"] or name

    @staticmethod
    def _fields() -> dict:
        return {f.name: f for f in fields(SolverConfig)}

    # -- validation ----------------------------------------------------------------------------------
    def validate(self) -> "SolverConfig":
        """Check every field against its declaration and the registries; return self.

        Raises
        ------
        SceneError
            With the ``solver.<key>`` path of the offending field.
        """
        for f in fields(self):
            setattr(self, f.name, _check(f, getattr(self, f.name), f"solver.{self.yaml_key(f.name)}"))
        if self.steps is not None and self.duration is not None:
            raise SceneError("solver", "give steps or duration, not both")
        from ..forces import JACOBIAN_MODES
        from ..integrators import integrator_class
        from ..integrators._implicit import FORCING_RULES, STAGE_SOLVERS
        from ..linsolve import linear_solver_class

        for name, check in (("integrator", integrator_class), ("linear_solver", linear_solver_class)):
            value = getattr(self, name)
            if value is not None:
                try:
                    check(value)
                except SceneError as e:
                    raise SceneError(f"solver.{self.yaml_key(name)}", e.message) from None
        def partitioners():
            # by module path, and only when asked for: the distributed package's lazy names (its driver) import
            # the drivers, which import this module; the partition module itself does not
            return importlib.import_module("..distributed.partition", __package__).PARTITIONERS

        for name, what, allowed in (("backend", "backend", lambda: BACKENDS),
                                    ("partitioner", "partitioner", partitioners),
                                    ("forcing", "forcing rule", lambda: FORCING_RULES),
                                    ("stage_solver", "stage solver", lambda: STAGE_SOLVERS),
                                    ("jacobian", "jacobian mode", lambda: JACOBIAN_MODES)):
            value = getattr(self, name)
            if value is not None:
                check_choice(value, allowed(), param=f"solver.{name}", what=what)
        return self

    @classmethod
    def from_yaml(cls, block, *, default_dt: float | None = None, extra: tuple[str, ...] = ()) -> tuple:
        """The config of a YAML ``solver:`` mapping, and the values of its ``extra`` keys (a dict).

        ``default_dt`` replaces a missing ``timestep`` (the ``benchmark_cloth`` block's 1/60 s). A key whose
        value is null (``timestep: null``, ``gravity: ~``) counts as not given: the field takes its default,
        and a required field without one is refused.

        Raises
        ------
        SceneError
            Naming ``solver.<key>`` for unknown, missing or invalid keys.
        """
        if type(block) is not dict:
            raise SceneTypeError("solver", f"must be a mapping, got {type(block).__name__}")
        by_key = {cls.yaml_key(n): n for n in cls._fields()}
        allowed = tuple(by_key) + tuple(extra)
        for k in block:
            if k not in allowed:
                raise SceneError("solver", f"unknown key {k!r:.60}; allowed: {', '.join(allowed)}")
        for key in ("type",) + (() if default_dt is not None else ("timestep",)):
            if key not in block:
                raise SceneError("solver", f"missing required key {key!r}")
            if block[key] is None:
                raise SceneError(f"solver.{key}", "is required and has no default; got null")
        values = {by_key[k]: v for k, v in block.items() if k in by_key and v is not None}
        values.setdefault("dt", default_dt)
        return cls(**values), {k: block[k] for k in extra if block.get(k) is not None}

    # -- command line -------------------------------------------------------------------------------------
    @classmethod
    def add_arguments(cls, parser, choices: dict | None = None, defaults: dict | None = None) -> None:
        """Add a flag for every field that declares one (type-checked, one-line errors).

        Parameters
        ----------
        parser : argparse.ArgumentParser
            The parser of a command that runs a scene.
        choices : dict, optional
            Field name -> the allowed names of a ``"name"`` field (checked by argparse, listed in ``--help``).
        defaults : dict, optional
            Field name -> the default its owner declares (a field whose default is None: the integrator's or
            solver's own), shown in ``--help`` in place of the help text's ``(default: ...)``.
        """
        import argparse

        choices = choices or {}
        defaults = defaults or {}
        steps_or_duration = parser.add_mutually_exclusive_group()
        for f in fields(cls):
            m = f.metadata
            if not m["cli"]:
                continue

            def convert(text, f=f):
                kind = f.metadata["kind"]
                if kind in ("name", "options"):
                    return text
                what = "an integer" if kind == "int" else "a number"
                if len(text) > 40:
                    raise argparse.ArgumentTypeError(f"must be {what}, got a {len(text)}-character value")
                try:
                    value = int(text) if kind == "int" else float(text)
                except ValueError:
                    raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None
                try:
                    return _check(f, value, f.metadata["cli"])
                except SceneError as e:
                    raise argparse.ArgumentTypeError(e.message) from None

            convert.__name__ = f.name
            help_ = m["help"]
            if f.name in defaults:
                help_ = f"{help_.partition(' (default')[0]} (default {defaults[f.name]:g})"
            if f.name in choices:
                help_ += f"; one of: {', '.join(choices[f.name])}"
            target = steps_or_duration if f.name in ("steps", "duration") else parser
            target.add_argument(m["cli"], *m["cli_aliases"], dest=f.name, type=convert, metavar=m["metavar"],
                                choices=choices.get(f.name), help=f"{help_} (overrides solver.{m['yaml'] or f.name})")

    def with_overrides(self, **overrides) -> "SolverConfig":
        """A validated copy with the non-None ``overrides`` applied (command-line flags); ``steps`` and ``duration``
        replace each other."""
        given = {k: v for k, v in overrides.items() if v is not None and k in self._fields()}
        if "steps" in given:
            given.setdefault("duration", None)
        if "duration" in given:
            given.setdefault("steps", None)
        return replace(self, **given)

    # -- what the options do ------------------------------------------------------------------------------
    @property
    def adaptive(self) -> bool:
        """Whether the run uses adaptive time stepping (a time tolerance is set)."""
        return self.time_rtol is not None or self.time_atol is not None

    def run_steps(self) -> int:
        """Steps of the run: ``steps``, else ``duration`` in steps of ``dt``, else :data:`DEFAULT_STEPS`."""
        if self.steps is not None:
            return self.steps
        if self.duration is not None:
            try:
                return steps_for_duration(self.duration, self.dt)
            except ValueError as e:
                raise SceneError("solver.duration", str(e)) from None
        return DEFAULT_STEPS

    def integrator_options(self) -> dict:
        """Keyword options for :func:`~springsim.integrators.make_integrator` (only those that are set)."""
        opts: dict = {}
        for f in fields(self):
            value, m = getattr(self, f.name), f.metadata
            if value is None or m["to"] == "run":
                continue
            if m["to"] == "solver":
                opts.setdefault("solver_options", {})[m["kwarg"] or f.name] = value
            else:
                opts[m["kwarg"] or f.name] = value
        return opts

    def unused(self, integrator=None) -> list[str]:
        """Fields that are set but have no effect on this run (the YAML keys): Newton options of integrators
        without Newton iterations, the options the built ``integrator``'s stage rule does not use, ``max_step``
        without adaptive stepping."""
        from ..integrators import integrator_class

        skip = integrator_class(self.integrator).unused_options
        if integrator is not None and hasattr(integrator, "ignored_options"):
            skip = skip | integrator.ignored_options()
        out = [self.yaml_key(f.name) for f in fields(self)
               if getattr(self, f.name) is not None and f.metadata["to"] != "run"
               and (f.metadata["kwarg"] or f.name) in skip]
        if self.linear_rtol is not None and "solver_options" in skip:
            out.append("linear_rtol")
        if self.max_step is not None and not self.adaptive:
            out.append("max_step")
        for name in ("petsc_options", "partitioner"):
            if getattr(self, name) is not None and self.backend != "petsc":
                out.append(name)
        return sorted(set(out))
