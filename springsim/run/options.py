"""Run options, declared once: the option groups and :class:`SolverConfig`, which composes them.

Every option a run takes (the YAML ``solver:`` block, the command-line flags of ``springsim run``,
the keywords of :func:`springsim.integrators.make_integrator` and the drivers) is one field of a frozen option
group, declared with :func:`option`: its type and bounds, default (a value, or a rule where it depends on the
stage rule or the integrator), help text, YAML key and command-line flag. The groups:

* :class:`~springsim.integrators.NewtonOptions`: how implicit stages are solved (``stage_solver``, ``jacobian``,
  ``force_rtol``, ``newton_tol``, ``newton_maxiter``, ...);
* :class:`~springsim.integrators.LinearSolveOptions`: the linear solver and ``linear_rtol``;
* :class:`TimeStepOptions`: the steps of the run (``timestep``, ``steps`` or ``duration``, the tolerances of
  adaptive stepping and ``max_step``);

and :class:`SolverConfig` composes them with the run-level fields (``type``, ``backend``, ``partitioner``,
``petsc_options``). The YAML parser (:meth:`SolverConfig.from_yaml`), the command-line flags and their
``--help`` defaults (:meth:`SolverConfig.add_arguments`), the keyword options
(:meth:`SolverConfig.integrator_options`) and the options a run leaves unused (:meth:`SolverConfig.unused`) are
all derived from the declarations, so adding an option is one field of a group.

Errors: the Python API raises :class:`~springsim.errors.SceneError` (a ``ValueError``) whose path is
the parameter (``jacobian: unknown jacobian mode ...``); :class:`SolverConfig` reports the YAML field path
(``solver.jacobian``), and the command line its flag.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass, field, fields

from ..errors import SceneError
from ..integrators._options import (LinearSolveOptions, OptionGroup, check_option, describe_default, describe_int,
                                    option, renamed)
from ..integrators._stage import NewtonOptions

__all__ = ["ADAPTIVE_H_MIN", "BACKENDS", "MAX_STEPS", "DEFAULT_STEPS",
           "SolverConfig", "TimeStepOptions", "option", "describe_int", "steps_for_duration"]

#: Largest number of steps a run may ask for (a guard against overflowing step counts).
MAX_STEPS = 10**12

#: Backends of a run: ``serial`` (one process), ``petsc`` (:mod:`springsim.distributed`, under ``mpiexec``).
BACKENDS = ("serial", "petsc")

#: Run length used when neither the scene nor the caller gives one.
DEFAULT_STEPS = 100

#: Smallest step of adaptive runs (the ``h_min`` default of :func:`springsim.run.adaptive.simulate_adaptive`):
#: the lower bound of ``max_step``.
ADAPTIVE_H_MIN = 1e-7


def steps_for_duration(duration: float, dt: float) -> int:
    """Steps of size ``dt`` that cover ``duration`` [s]: ``ceil(duration / dt)`` (a relative 1e-9 slack absorbs
    rounding, so 1.0 / 0.01 is 100 steps); at least 1 for a positive duration, 0 for 0.

    Parameters
    ----------
    duration : float
        Simulated time [s].
    dt : float
        Step [s].

    Returns
    -------
    int
        The number of steps.

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


@dataclass(frozen=True)
class TimeStepOptions(OptionGroup):
    """The steps of a run: their size and number, or the tolerances of adaptive stepping.

    Each field is declared once (:func:`option`); ``None`` stands for the declared default, and the defaults
    that are rules are implemented here (:meth:`run_steps`, :meth:`tolerances`) or by the adaptive driver
    (``max_step``: its ``h_max``).

    Parameters
    ----------
    dt : float, optional
        Time step [s] (YAML ``timestep``, flag ``--dt``); with adaptive stepping the first step and the frame
        spacing.
    steps : int, optional
        Number of steps (default: from ``duration``, else :data:`DEFAULT_STEPS`).
    duration : float, optional
        Simulated time [s]; ``steps = ceil(duration / dt)``. Not with ``steps``.
    time_rtol, time_atol : float, optional
        Relative and absolute local error tolerances of adaptive time stepping (:meth:`tolerances`).
    max_step : float, optional
        Largest step of adaptive time stepping [s], at least :data:`ADAPTIVE_H_MIN` (default a tenth of the
        run).

    Raises
    ------
    SceneError
        Naming the field of a value its declaration refuses; with the path ``""`` for ``steps`` and
        ``duration`` together.
    """

    dt: float | None = option(None, kind="float", yaml="timestep", cli="--dt", metavar="H", lo=0.0, strict=True,
                              default_text="the scene's solver.timestep",
                              help="time step [s]; with adaptive stepping the first step and the frame spacing")
    steps: int | None = option(None, kind="int", cli="--steps", metavar="N", lo=0, hi=MAX_STEPS,
                               default_text=f"from duration, else {DEFAULT_STEPS}", help="number of steps")
    duration: float | None = option(None, kind="float", cli="--duration", metavar="T", lo=0.0,
                                    help="simulated time [s] (steps = ceil(T/dt)); give steps or duration")
    time_rtol: float | None = option(None, kind="float", cli="--time-rtol", metavar="R", lo=0.0, strict=True,
                                     default_text="fixed steps; with only time_atol, equal to it",
                                     help="adaptive time stepping (bdf2, tr_bdf2, energy_momentum): relative local "
                                          "error tolerance")
    time_atol: float | None = option(None, kind="float", cli="--time-atol", metavar="A", lo=0.0, strict=True,
                                     default_text="time_rtol",
                                     help="adaptive time stepping: absolute local error tolerance [m, m/s]")
    max_step: float | None = option(None, kind="float", cli="--max-step", metavar="H", lo=ADAPTIVE_H_MIN,
                                    needs="adaptive", default_text="a tenth of the run",
                                    help=f"adaptive time stepping: largest step [s], at least {ADAPTIVE_H_MIN:g} s")

    def check_combination(self) -> None:
        """``steps`` and ``duration`` are not both given.

        Raises
        ------
        SceneError
            With the path ``""`` (the combination).
        """
        if self.steps is not None and self.duration is not None:
            raise SceneError("", "give steps or duration, not both")

    @property
    def adaptive(self) -> bool:
        """Whether the run uses adaptive time stepping (a time tolerance is set)."""
        return self.time_rtol is not None or self.time_atol is not None

    def tolerances(self) -> tuple[float, float]:
        """The relative and absolute tolerances of adaptive stepping: each defaults to the other.

        Returns
        -------
        time_rtol, time_atol : float

        Raises
        ------
        ValueError
            When neither is given (the run is not adaptive).
        """
        if not self.adaptive:
            raise ValueError("fixed steps: no time tolerance is given")
        rtol = self.time_rtol if self.time_rtol is not None else self.time_atol
        atol = self.time_atol if self.time_atol is not None else self.time_rtol
        return rtol, atol

    def run_steps(self) -> int:
        """Steps of the run: ``steps``, else ``duration`` in steps of ``dt``, else :data:`DEFAULT_STEPS`.

        Returns
        -------
        int

        Raises
        ------
        SceneError
            Naming ``duration`` when it needs more than :data:`MAX_STEPS` steps.
        """
        if self.steps is not None:
            return self.steps
        if self.duration is not None:
            try:
                return steps_for_duration(self.duration, self.dt)
            except ValueError as e:
                raise SceneError("duration", str(e)) from None
        return DEFAULT_STEPS


def _integrators():
    """The registered integrator names (looked up when checked: integrators registered later count)."""
    from ..integrators import INTEGRATORS

    return INTEGRATORS


def _partitioners():
    """The partitioner names of the petsc backend, by module path and only when asked for: the distributed
    package's lazy names (its driver) import the drivers, which import this module; the partition module itself
    does not."""
    return importlib.import_module("..distributed.partition", __package__).PARTITIONERS


#: The option groups of :class:`SolverConfig`: attribute -> group class.
GROUPS = {"time": TimeStepOptions, "linear": LinearSolveOptions, "newton": NewtonOptions}


@dataclass(frozen=True, init=False)
class SolverConfig:
    """How to run a scene: the ``solver:`` block of a YAML scene, the flags of ``springsim run``.

    The option groups (:data:`GROUPS`: :class:`TimeStepOptions` as ``time``, :class:`LinearSolveOptions` as
    ``linear``, :class:`NewtonOptions` as ``newton``) and the run-level fields, every field declared once
    (module docstring). The groups' fields read as attributes too (``config.dt``, ``config.jacobian``), and
    the constructor takes them as keywords, which override the fields of a group given (``SolverConfig(dt=0.01,
    jacobian="spd")``). ``None`` stands for the declared default. The config is frozen and checked on
    construction.

    Parameters
    ----------
    integrator : str
        A registered integrator (YAML ``type``, flag ``--integrator``); default ``"implicit_euler"``.
    time : TimeStepOptions, optional
        The steps of the run.
    linear : LinearSolveOptions, optional
        The linear solver of implicit integrators.
    newton : NewtonOptions, optional
        How implicit stages are solved.
    backend : {"serial", "petsc"}, optional
        Where the run executes (default ``serial``).
    partitioner : str, optional
        How the petsc backend splits the particles over the ranks (default ``contiguous``).
    petsc_options : str or dict, optional
        PETSc options of the petsc backend.
    **options
        The fields of the groups by name (``dt``, ``steps``, ``linear_solver``, ``jacobian``, ...).

    Raises
    ------
    SceneError
        Naming ``solver.<key>`` (the YAML path) of a value a declaration refuses.
    TypeError
        For an unknown keyword, or a group of the wrong class.
    """

    integrator: str = option("implicit_euler", kind="name", yaml="type", cli="--integrator", metavar="NAME",
                             choices=_integrators, what="integrator", default_text="the scene's solver.type",
                             filled=True, help="time integrator")
    time: TimeStepOptions = field(default_factory=TimeStepOptions)
    linear: LinearSolveOptions = field(default_factory=LinearSolveOptions)
    newton: NewtonOptions = field(default_factory=NewtonOptions)
    backend: str | None = option("serial", kind="name", cli="--backend", metavar="NAME", choices=BACKENDS,
                                 what="backend", help="serial or petsc: distributed assembly and solves on PETSc, "
                                                      "run under mpiexec (docs/distributed.md)")
    partitioner: str | None = option("contiguous", kind="name", cli="--partitioner", metavar="NAME",
                                     choices=_partitioners, what="partitioner", needs="petsc",
                                     help="petsc backend: how the particles are split over the ranks: contiguous "
                                          "(blocks of the serial numbering) or a graph partitioner of PETSc "
                                          "(ptscotch, parmetis)")
    petsc_options: str | dict | None = option(None, kind="options", cli="--petsc-options", metavar="OPTS",
                                              needs="petsc",
                                              help="PETSc options of the petsc backend, e.g. '-ksp_type gmres "
                                                   "-pc_gamg_threshold 0.02' (in YAML also a mapping; PETSC_OPTIONS "
                                                   "applies too)")

    def __init__(self, integrator: str = "implicit_euler", *, time: TimeStepOptions | None = None,
                 linear: LinearSolveOptions | None = None, newton: NewtonOptions | None = None,
                 backend: str | None = None, partitioner: str | None = None, petsc_options=None, **options):
        groups = {"time": time, "linear": linear, "newton": newton}
        try:
            for attr, cls in GROUPS.items():
                given = groups[attr]
                if given is not None and not isinstance(given, cls):
                    raise TypeError(f"{attr} must be a {cls.__name__}, got {type(given).__name__}")
                mine = {k: options.pop(k) for k in list(options) if k in cls.declarations()}
                if given is None or mine:
                    values = {**({} if given is None else given.given()), **mine}  # keywords override the group
                    given = cls(**{k: v for k, v in values.items() if v is not None})
                object.__setattr__(self, attr, given)
            if options:
                raise TypeError(f"SolverConfig() got an unexpected keyword argument {next(iter(options))!r}")
            own = {f.name: f for f in fields(self) if f.name not in GROUPS}
            for name, value in (("integrator", integrator), ("backend", backend), ("partitioner", partitioner),
                                ("petsc_options", petsc_options)):
                object.__setattr__(self, name, check_option(own[name], value, name))
        except SceneError as e:
            raise renamed(e, {"": "solver", **{n: f"solver.{self.yaml_key(n)}" for n in self.declarations()}}) \
                from None

    # -- declarations --------------------------------------------------------------------------------
    @classmethod
    def declarations(cls) -> dict:
        """Every option of a run by field name, in declaration order: ``(group, field)``.

        Returns
        -------
        dict
            Field name -> ``(attribute of its group in the config, or None for a run-level field,
            dataclasses.Field)``.
        """
        out = {}
        for f in fields(cls):
            if f.name in GROUPS:
                out.update({name: (f.name, g) for name, g in GROUPS[f.name].declarations().items()})
            else:
                out[f.name] = (None, f)
        return out

    @classmethod
    def yaml_key(cls, name: str) -> str:
        """The ``solver:`` key of field ``name`` (a Python-only option: its name).

        Parameters
        ----------
        name : str
            A field name (:meth:`declarations`).

        Returns
        -------
        str
        """
        return cls.declarations()[name][1].metadata["yaml"] or name

    @classmethod
    def keyword(cls, name: str) -> str:
        """The :func:`~springsim.integrators.make_integrator` keyword of field ``name``.

        Parameters
        ----------
        name : str
            A field name (:meth:`declarations`).

        Returns
        -------
        str
        """
        return cls.declarations()[name][1].metadata["kwarg"] or name

    @classmethod
    def default(cls, name: str):
        """The declared default of field ``name`` (a value, a rule, or None).

        Parameters
        ----------
        name : str
            A field name (:meth:`declarations`).

        Returns
        -------
        object
        """
        return cls.declarations()[name][1].metadata["default"]

    def flat(self) -> dict:
        """Every field's value by name, the groups' included (None: not given).

        Returns
        -------
        dict
        """
        return {name: getattr(self, name) for name in self.declarations()}

    # -- validation ----------------------------------------------------------------------------------
    def validate(self) -> "SolverConfig":
        """The config itself: it was checked on construction (kept for callers of the former mutable config).

        Returns
        -------
        SolverConfig
            ``self``.
        """
        return self

    @classmethod
    def from_yaml(cls, block, *, default_dt: float | None = None, extra: tuple[str, ...] = ()) -> tuple:
        """The config of a YAML ``solver:`` mapping, and the values of its ``extra`` keys (a dict).

        ``default_dt`` replaces a missing ``timestep`` (the ``benchmark_cloth`` block's 1/60 s). A key whose
        value is null (``timestep: null``, ``gravity: ~``) counts as not given: the field takes its default,
        and a required field without one is refused.

        Parameters
        ----------
        block : dict
            The ``solver:`` mapping.
        default_dt : float, optional
            The time step when the block has none.
        extra : tuple of str
            Other keys the block may hold (the model's ``gravity`` and ``up_axis``).

        Returns
        -------
        config : SolverConfig
        extra : dict
            The values of the ``extra`` keys given.

        Raises
        ------
        SceneError
            Naming ``solver.<key>`` for unknown, missing or invalid keys.
        """
        from ..errors import SceneTypeError

        if type(block) is not dict:
            raise SceneTypeError("solver", f"must be a mapping, got {type(block).__name__}")
        by_key = {f.metadata["yaml"] or n: n for n, (_, f) in cls.declarations().items()
                  if f.metadata["yaml"] is not False}
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
    def help_text(cls, name: str) -> str:
        """The ``--help`` line of field ``name``: its help, its default rendered from the declaration, and the
        names it allows.

        Parameters
        ----------
        name : str
            A field name (:meth:`declarations`).

        Returns
        -------
        str
        """
        f = cls.declarations()[name][1]
        m = f.metadata
        text = m["help"]
        default = describe_default(f)
        if default is not None:
            shown = m["default_text"] is not None or not isinstance(m["default"], (str, int, float))
            text += f" (default: {default})" if shown else f" (default {default})"
        if m["kind"] == "name" and m["choices"] is not None:
            text += f"; one of: {', '.join(cls._choices(f))}"
        return text

    @staticmethod
    def _choices(f) -> list:
        choices = f.metadata["choices"]
        return list(choices() if callable(choices) else choices)

    @classmethod
    def add_arguments(cls, parser) -> None:
        """Add a flag for every field that declares one (type-checked, one-line errors, the default and the allowed
        names in ``--help`` from the declaration).

        Parameters
        ----------
        parser : argparse.ArgumentParser
            The parser of a command that runs a scene.
        """
        import argparse

        steps_or_duration = parser.add_mutually_exclusive_group()
        for name, (_, f) in cls.declarations().items():
            m = f.metadata
            if not m["cli"]:
                continue

            def convert(text, f=f):
                kind = f.metadata["kind"]
                if kind in ("name", "options"):
                    return text  # names: argparse checks the choices
                what = "an integer" if kind == "int" else "a number"
                if len(text) > 40:
                    raise argparse.ArgumentTypeError(f"must be {what}, got a {len(text)}-character value")
                try:
                    value = int(text) if kind == "int" else float(text)
                except ValueError:
                    raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None
                try:
                    return check_option(f, value, f.metadata["cli"])
                except SceneError as e:
                    raise argparse.ArgumentTypeError(e.message) from None

            convert.__name__ = name
            choices = cls._choices(f) if m["kind"] == "name" and m["choices"] is not None else None
            target = steps_or_duration if name in ("steps", "duration") else parser
            target.add_argument(m["cli"], *m["cli_aliases"], dest=name, type=convert, metavar=m["metavar"],
                                choices=choices, help=f"{cls.help_text(name)} (overrides solver.{cls.yaml_key(name)})")

    def with_overrides(self, **overrides) -> "SolverConfig":
        """A checked copy with the non-None ``overrides`` applied (command-line flags); ``steps`` and ``duration``
        replace each other.

        Parameters
        ----------
        **overrides
            Field name -> value (None, or a name that is no field: ignored).

        Returns
        -------
        SolverConfig

        Raises
        ------
        SceneError
            Naming ``solver.<key>`` of an invalid value.
        """
        given = {k: v for k, v in overrides.items() if v is not None and k in self.declarations()}
        if "steps" in given:
            given.setdefault("duration", None)
        if "duration" in given:
            given.setdefault("steps", None)
        return SolverConfig(**{**self.flat(), **given})

    # -- what the options do ------------------------------------------------------------------------------
    @property
    def adaptive(self) -> bool:
        """Whether the run uses adaptive time stepping (a time tolerance is set)."""
        return self.time.adaptive

    @property
    def petsc(self) -> bool:
        """Whether the run executes on the petsc backend."""
        return self.backend == "petsc"

    def run_steps(self) -> int:
        """Steps of the run: ``steps``, else ``duration`` in steps of ``dt``, else :data:`DEFAULT_STEPS`.

        Returns
        -------
        int

        Raises
        ------
        SceneError
            Naming ``solver.duration`` when it needs more than :data:`MAX_STEPS` steps.
        """
        try:
            return self.time.run_steps()
        except SceneError as e:
            raise renamed(e, {"duration": "solver.duration"}) from None

    def integrator_options(self) -> dict:
        """Keyword options for :func:`~springsim.integrators.make_integrator`: the fields of the linear solve and
        Newton groups that are set, by their keywords.

        Returns
        -------
        dict
        """
        return {self.keyword(name): value for group in (self.linear, self.newton)
                for name, value in group.given().items()}

    def unused(self, integrator=None) -> list[str]:
        """Fields that are set but have no effect on this run (their YAML keys), derived from the declarations.

        The options the integrator class does not read (its ``unused_options``: Newton options of integrators
        without Newton iterations, ...), those the stage rule of the built ``integrator`` does not read (its
        ``ignored_options()``), and those whose declaration ``needs`` a property the run lacks (``max_step``
        without adaptive stepping, the petsc backend's options on the serial one).

        Parameters
        ----------
        integrator : Integrator, optional
            The integrator built for this config.

        Returns
        -------
        list of str
            Sorted.
        """
        from ..integrators import integrator_class

        skip = integrator_class(self.integrator).unused_options
        if integrator is not None and hasattr(integrator, "ignored_options"):
            skip = skip | integrator.ignored_options()
        out = []
        for name, (group, f) in self.declarations().items():
            if getattr(self, name) is None:
                continue
            needs = f.metadata["needs"]
            if (group in ("linear", "newton") and self.keyword(name) in skip) or (needs and not getattr(self, needs)):
                out.append(self.yaml_key(name))
        return sorted(out)


def _flat_attribute(group: str, name: str) -> property:
    """A read-only attribute of :class:`SolverConfig` for field ``name`` of its group ``group``."""
    return property(lambda self: getattr(getattr(self, group), name),
                    doc=f"``{group}.{name}`` (:class:`{GROUPS[group].__name__}`).")


for _group, _cls in GROUPS.items():
    for _name in _cls.declarations():
        setattr(SolverConfig, _name, _flat_attribute(_group, _name))
del _group, _cls, _name
