"""Run options declared once (issue 33, goal 3): every option is one field of one frozen group with one name,
one default, one YAML key and one flag; the three surfaces (YAML, command line, Python keywords) reach the same
field, check it by the same declaration and name it their own way; ``--help`` shows the declared defaults; the
options an integrator ignores are derived from what its stage rule reads."""

from __future__ import annotations

import argparse
import dataclasses
import re
import warnings

import numpy as np
import pytest

from springsim.errors import SceneError, UnusedOptionWarning
from springsim.integrators import INTEGRATORS, LinearSolveOptions, NewtonOptions, make_integrator
from springsim.integrators._options import ByRule, DefaultRule, describe_default, format_value
from springsim.run.options import GROUPS, SolverConfig, TimeStepOptions
from springsim.scene import load_scene
from springsim.scene.gallery import benchmark_cloth

HEAD = "solver: {type: implicit_euler, timestep: 0.01%s}\nparticles: [{pos: [0,0,0], mass: 1}]\n"
DECL = SolverConfig.declarations()
CLI_FIELDS = [n for n, (_, f) in DECL.items() if f.metadata["cli"]]
YAML_FIELDS = [n for n, (_, f) in DECL.items() if f.metadata["yaml"] is not False]
GROUP_FIELDS = [n for n, (g, _) in DECL.items() if g in ("linear", "newton")]


def _parser():
    from springsim.cli.runner import add_run_options

    p = argparse.ArgumentParser(prog="t", exit_on_error=False)
    add_run_options(p)
    return p


def _sample(name: str):
    """A valid value of field ``name`` that is not its default (a value every surface can spell)."""
    m = DECL[name][1].metadata
    special = {"integrator": "bdf2", "jacobian": "spd", "stage_solver": "residual", "forcing": "eisenstat-walker",
               "linear_solver": "cg", "backend": "serial", "partitioner": "contiguous",
               "petsc_options": "-ksp_type gmres"}
    if name in special:
        return special[name]
    if m["kind"] == "bool":
        return not m["default"]
    lo, hi = m["lo"] or 0, m["hi"]
    if m["kind"] == "int":
        return int(lo) + 2
    return (lo + hi) / 2 if hi is not None else lo + 0.25


def _invalid(name: str):
    """A value field ``name``'s declaration refuses: below its lower bound, or an unknown name."""
    m = DECL[name][1].metadata
    if m["kind"] == "name":
        return "bogus"
    if m["kind"] == "bool":
        return 3
    return (int(m["lo"]) - 1) if m["kind"] == "int" else float(m["lo"]) - 1.0


def test_every_option_is_declared_once():
    """One declaration per option: names, YAML keys, flags (aliases included) and keywords are unique across the
    groups and the run-level fields; every field has a help line and a kind."""
    names = [n for cls in GROUPS.values() for n in cls.declarations()]
    names += [f.name for f in dataclasses.fields(SolverConfig) if f.name not in GROUPS]
    assert len(names) == len(set(names)) == len(DECL)
    keys = [SolverConfig.yaml_key(n) for n in YAML_FIELDS]
    assert len(keys) == len(set(keys))
    flags = [flag for n in CLI_FIELDS for flag in (DECL[n][1].metadata["cli"], *DECL[n][1].metadata["cli_aliases"])]
    assert len(flags) == len(set(flags))
    kws = [SolverConfig.keyword(n) for n in DECL]
    assert len(kws) == len(set(kws))
    for name, (_, f) in DECL.items():
        assert f.metadata["help"] and f.metadata["kind"] in ("name", "float", "int", "bool", "options"), name
        assert "default" not in f.metadata["help"], f"{name}: the default is rendered, not written in the help"
    # the Newton options each declare the stage rules that read them
    assert all(f.metadata["rules"] for f in NewtonOptions.declarations().values())


@pytest.mark.parametrize("name", YAML_FIELDS)
def test_yaml_cli_and_keyword_reach_the_same_field(name):
    """YAML key, flag and Python keyword of a field round-trip to the same group field."""
    group, f = DECL[name]
    value = _sample(name)
    key = SolverConfig.yaml_key(name)
    text = value if not isinstance(value, str) else f"'{value}'"
    if key == "type":
        cfg = load_scene(HEAD.replace("implicit_euler", value) % "").config
    elif key == "timestep":
        cfg = load_scene(HEAD.replace("0.01", str(value)) % "").config
    else:
        cfg = load_scene(HEAD % f", {key}: {text}").config
    assert getattr(cfg if group is None else getattr(cfg, group), name) == value == getattr(cfg, name)
    assert SolverConfig(**{name: value}) == SolverConfig(**{name: value}).with_overrides()
    if f.metadata["cli"]:
        args = _parser().parse_args([f.metadata["cli"], str(value)])
        assert getattr(args, name) == value
        assert getattr(SolverConfig(dt=0.01).with_overrides(**vars(args)), name) == value
    if group in ("linear", "newton"):
        kw = SolverConfig.keyword(name)
        assert cfg.integrator_options() == {kw: value}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UnusedOptionWarning)
            integ = make_integrator("implicit_euler", benchmark_cloth(3), **{kw: value})
        got = integ.linear_options if group == "linear" else integ.options
        assert getattr(got, name) == value


@pytest.mark.parametrize("cls", [NewtonOptions, LinearSolveOptions, TimeStepOptions])
def test_groups_are_frozen(cls):
    group = cls()
    name = next(iter(cls.declarations()))
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(group, name, _sample(name))
    cfg = SolverConfig(dt=0.01)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.dt = 0.02
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.newton = NewtonOptions()


@pytest.mark.parametrize("name", [n for n, (_, f) in DECL.items()
                                  if f.metadata["lo"] is not None or f.metadata["choices"] is not None])
def test_invalid_values_name_their_path_on_every_surface(name):
    """The same declaration refuses a value everywhere: YAML names ``solver.<key>``, the command line the flag,
    Python the parameter."""
    group, f = DECL[name]
    bad = _invalid(name)
    key = SolverConfig.yaml_key(name)
    if f.metadata["yaml"] is not False and key not in ("type", "timestep"):
        with pytest.raises(SceneError, match=rf"^solver\.{key}: "):
            load_scene(HEAD % f", {key}: {bad}")
    with pytest.raises(SceneError, match=rf"^solver\.{key}: "):
        SolverConfig(**{"dt": 0.01, name: bad})
    if f.metadata["cli"]:
        with pytest.raises(argparse.ArgumentError, match=re.escape(f.metadata["cli"])):
            _parser().parse_args([f.metadata["cli"], str(bad)])
    if group is not None:
        with pytest.raises(SceneError, match=rf"^{name}: "):
            GROUPS[group](**{name: bad})
    if group in ("linear", "newton"):
        kw = SolverConfig.keyword(name)
        with pytest.raises(SceneError, match=rf"^{kw}: "):
            make_integrator("implicit_euler", benchmark_cloth(3), **{kw: bad})


def test_help_shows_the_declared_defaults():
    """Every flag's ``--help`` ends with the default rendered from its declaration: values as declared (parsed
    back, equal), rules in words (from the rule itself)."""
    actions = {a.dest: a for a in _parser()._actions}
    for name in CLI_FIELDS:
        f = DECL[name][1]
        text = describe_default(f)
        help_ = actions[name].help
        if text is None:
            assert "(default" not in help_, name
            continue
        assert f"(default {text})" in help_ or f"(default: {text})" in help_, name
        d = f.metadata["default"]
        if isinstance(d, float):
            shown = re.search(r"\(default ([^)]*)\)", help_).group(1)
            assert float(shown) == d, name
        elif isinstance(d, ByRule):
            for rule, value in d.values.items():
                assert value is None or f"{format_value(value)} for {rule}" in help_, name
        elif isinstance(d, DefaultRule):
            assert d.describe() in " ".join(help_.split()), name


def test_declared_defaults_are_the_defaults_used():
    """A built integrator's resolved options hold the declared defaults and rules (no other default exists)."""
    model = benchmark_cloth(3)
    for name, cls in INTEGRATORS.items():
        if not cls.implicit:
            continue
        integ = make_integrator(name, model, solver="direct")
        o = integ.options
        assert o.resolved
        for field_name, f in NewtonOptions.declarations().items():
            d = f.metadata["default"]
            if isinstance(d, ByRule):
                assert getattr(o, field_name) == d.value(o.stage_solver, cls), (name, field_name)
            elif isinstance(d, DefaultRule):
                assert getattr(o, field_name) == d.fn(integ, NewtonOptions(), o.given()), (name, field_name)
            else:
                assert getattr(o, field_name) == d, (name, field_name)
    assert make_integrator("implicit_euler", model, solver="cg").system.linear_rtol == \
        LinearSolveOptions.default("linear_rtol")


def test_groups_and_keywords_are_one_path():
    """make_integrator takes the groups or their fields as keywords; the same value twice is fine, two
    different ones are refused naming the keyword."""
    model = benchmark_cloth(3)
    a = make_integrator("implicit_euler", model, newton=NewtonOptions(jacobian="spd", newton_maxiter=7),
                        linear=LinearSolveOptions(linear_solver="cg", linear_rtol=1e-9))
    b = make_integrator("implicit_euler", model, jacobian="spd", newton_maxiter=7, solver="cg", linear_rtol=1e-9)
    assert a.options == b.options and a.system.linear_rtol == b.system.linear_rtol == 1e-9
    assert make_integrator("implicit_euler", model, newton=NewtonOptions(jacobian="spd"), jacobian="spd").jacobian \
        == "spd"
    with pytest.raises(SceneError, match=r"^jacobian: given twice"):
        make_integrator("implicit_euler", model, newton=NewtonOptions(jacobian="spd"), jacobian="mixed")
    with pytest.raises(TypeError):
        make_integrator("implicit_euler", model, newton=LinearSolveOptions())
    # a group given to an explicit integrator is named field by field
    with pytest.warns(UnusedOptionWarning, match=r"symplectic_euler does not use the option\(s\) newton_tol; "):
        make_integrator("symplectic_euler", model, newton=NewtonOptions(newton_tol=1e-7))
    cfg = SolverConfig(dt=0.01, newton=NewtonOptions(forcing="eisenstat-walker"), jacobian="spd")
    assert cfg.newton == NewtonOptions(forcing="eisenstat-walker", jacobian="spd") and cfg.forcing == "eisenstat-walker"


class _Recorder:
    """A resolved NewtonOptions that records which fields are read."""

    def __init__(self, options):
        self._options, self.read = options, set()

    def __getattr__(self, name):
        self.read.add(name)
        return getattr(self._options, name)


@pytest.mark.parametrize("rule", ["minimize", "residual", "pa2"])
def test_stage_rules_read_what_they_declare(rule):
    """A stage solved with each rule reads no Newton option its declarations say it ignores: the unused-option
    warnings, derived from the declarations, are true."""
    model = benchmark_cloth(4)
    integ = make_integrator("implicit_euler", model, solver="direct", stage_solver=rule, newton_maxiter=3,
                            on_nonconvergence="ignore", jacobian="exact" if rule != "minimize" else None)
    integ.stage.options = rec = _Recorder(integ.options)
    state = model.state()
    state.particle_qd[...] = np.random.default_rng(0).normal(size=state.particle_qd.shape)
    integ.step(state, model.state(), 0.05)
    assert rec.read, rule
    assert rec.read <= NewtonOptions.read_by(rule), rec.read - NewtonOptions.read_by(rule)


def test_unused_options_follow_the_declared_reads():
    """The integrators' unused options and their rules' ignored options are the declared complements."""
    every = frozenset(NewtonOptions.declarations())
    for name, cls in INTEGRATORS.items():
        if not cls.implicit:
            continue
        rules = cls.stage_solvers if cls.converges else ("plain",)
        read = frozenset().union(*(NewtonOptions.read_by(r) for r in rules))
        assert cls.unused_options - {"filter_estimates"} == every - read, name
    assert NewtonOptions.read_by("pa2") >= {"newton_tol", "newton_maxiter"}
    assert "force_rtol" not in NewtonOptions.read_by("pa2")
    assert NewtonOptions.read_by("plain") == {"stage_solver", "jacobian"}
    cfg = SolverConfig(integrator="implicit_euler", dt=0.01, stage_solver="pa2", force_rtol=1e-3, newton_tol=1e-6)
    integ = make_integrator("implicit_euler", benchmark_cloth(3), **{"stage_solver": "pa2"})
    assert cfg.unused(integ) == ["force_rtol"]


def test_kernels_options_share_one_vocabulary():
    """The forces' ``force_kernels`` and the AMG preconditioner's ``kernels`` take the same values, checked by
    one function; the AMG's former ``"scipy"`` maps to ``"numpy"`` with a DeprecationWarning on both."""
    from springsim._runtime.accel import KERNELS, check_kernels
    from springsim.forces import make_force_terms
    from springsim.linsolve import make_linear_solver

    assert KERNELS == ("auto", "numba", "numpy")
    assert [check_kernels(k) for k in KERNELS] == list(KERNELS)
    model = benchmark_cloth(3)
    for value in KERNELS:
        make_force_terms(model, kernels=value)
        assert make_linear_solver("amg-cg", kernels=value).preconditioner.kernels in ("numba", "numpy")
    for build in (lambda k: make_force_terms(model, kernels=k),
                  lambda k: make_integrator("symplectic_euler", model, force_kernels=k),
                  lambda k: make_linear_solver("amg-cg", kernels=k)):
        with pytest.raises(ValueError, match="^kernels must be one of 'auto', 'numba', 'numpy', got 'fortran'$"):
            build("fortran")
        with pytest.warns(DeprecationWarning, match="^kernels='scipy' is deprecated; use 'numpy'"):
            build("scipy")
    with pytest.warns(DeprecationWarning):
        assert make_linear_solver("amg-cg", kernels="scipy").preconditioner.kernels == "numpy"
    with pytest.warns(DeprecationWarning):
        assert all(getattr(t, "kernels", "numpy") == "numpy"
                   for t in make_force_terms(benchmark_cloth(40), kernels="scipy"))


def test_scene_format_lists_every_yaml_option():
    """docs/scene-format.md's solver table has a row for every YAML key the declarations give, with the declared
    default of those that have a value."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "scene-format.md").read_text()
    rows = {}
    for line in text.split("## `solver`")[1].split("\n\n")[1].splitlines()[2:]:
        cells = [c.strip() for c in line.strip("|").split(" | ")]
        for key in re.findall(r"`([a-z_]+)`", cells[0]):
            rows[key] = cells[2]
    for name in YAML_FIELDS:
        key = SolverConfig.yaml_key(name)
        assert key in rows, key
        d = DECL[name][1].metadata["default"]
        if isinstance(d, float):
            assert float(rows[key].split()[0]) == d, (key, rows[key])
        elif isinstance(d, str) and name != "integrator":
            assert f"`{d}`" in rows[key], (key, rows[key])


@pytest.mark.parametrize("cls", [NewtonOptions, LinearSolveOptions, TimeStepOptions])
def test_group_docstrings_state_the_declared_defaults(cls):
    """A group's docstring documents each field; where it states a default value, it is the declared one."""
    doc = cls.__doc__
    params = doc.split("Parameters\n    ----------\n")[1].split("\n    Raises")[0]
    entries = re.split(r"\n    (?=[a-z_, ]+ : )", "\n" + params)
    by_name = {}
    for entry in filter(str.strip, entries):
        head, _, body = entry.strip().partition(" : ")
        for name in head.split(", "):
            by_name[name] = " ".join(body.split())
    assert set(by_name) == set(cls.declarations()), set(cls.declarations()) ^ set(by_name)
    for name, f in cls.declarations().items():
        d, text = f.metadata["default"], by_name[name]
        if isinstance(d, bool) or isinstance(d, str):
            assert str(d) in text, (name, text)
        elif isinstance(d, float) and name != "linear_rtol":
            numbers = [float(x) for x in re.findall(r"(?<![\w.*])\d+(?:\.\d+)?(?:e-?\d+)?(?![\w*])", text)]
            assert d in numbers, (name, text)
    if cls is LinearSolveOptions:
        assert "DEFAULT_RTOL" in by_name["linear_rtol"]
