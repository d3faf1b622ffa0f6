"""Run options with one name and one default: ``linear_rtol`` everywhere, its default declared once; names
checked by one function."""

import argparse
import inspect
import warnings

import pytest

from springsim import make_integrator
from springsim.errors import SceneError, UnusedOptionWarning, check_choice
from springsim.linsolve import DEFAULT_RTOL, LINEAR_SOLVERS, make_linear_solver
from springsim.scene import load_scene

SCENE = "solver: {type: implicit_euler, timestep: 0.01, steps: 2}\nparticles: [{pos: [0,0,0], mass: 1}]\n"


def _parse(*argv):
    from springsim.cli.runner import add_run_options

    p = argparse.ArgumentParser()
    add_run_options(p)
    return p, p.parse_args(list(argv))


def test_linear_rtol_default_is_declared_once():
    """Every linear solver, the PETSc system and the distributed drivers default to DEFAULT_RTOL."""
    from springsim.distributed.driver import make_distributed, simulate_distributed
    from springsim.distributed.system import DistributedSystem

    assert DEFAULT_RTOL == 1e-6
    for name in LINEAR_SOLVERS:
        assert make_linear_solver(name).rtol == DEFAULT_RTOL, name
    for fn, param in ((make_distributed, "linear_rtol"), (simulate_distributed, "linear_rtol"),
                      (DistributedSystem, "rtol")):
        assert inspect.signature(fn).parameters[param].default == DEFAULT_RTOL
    model = load_scene(SCENE).model
    assert make_integrator("implicit_euler", model, solver="cg").system.linear_rtol == DEFAULT_RTOL


def test_linear_rtol_on_the_command_line_and_its_old_flag():
    """``--linear-rtol`` sets linear_rtol; ``--rtol`` is kept as its alias; --help shows the declared default."""
    p, args = _parse("--linear-rtol", "1e-9")
    assert args.linear_rtol == 1e-9
    assert _parse("--rtol", "1e-8")[1].linear_rtol == 1e-8
    assert _parse()[1].linear_rtol is None
    help_ = " ".join(p.format_help().split())
    assert "--linear-rtol R, --rtol R" in help_ and f"(default {DEFAULT_RTOL:g})" in help_


def test_linear_rtol_in_yaml_and_python_reaches_the_solver():
    """``solver.linear_rtol`` in YAML, ``linear_rtol=`` of make_integrator and the older
    ``solver_options={"rtol": ...}`` all set the linear solver's tolerance."""
    scene = load_scene(SCENE.replace("steps: 2", "steps: 2, linear_solver: cg, linear_rtol: 1.0e-9"))
    assert scene.config.linear_rtol == 1e-9
    opts = scene.config.integrator_options()
    assert make_integrator("implicit_euler", scene.model, **opts).solver.rtol == 1e-9
    model = scene.model
    new = make_integrator("implicit_euler", model, solver="cg", linear_rtol=1e-9)
    old = make_integrator("implicit_euler", model, solver="cg", solver_options={"rtol": 1e-9})
    assert new.solver.rtol == old.solver.rtol == new.system.linear_rtol == 1e-9
    both = make_integrator("implicit_euler", model, solver="cg", linear_rtol=1e-9,
                           solver_options={"rtol": 1e-9, "maxiter": 7})
    assert both.solver.rtol == 1e-9 and both.solver.maxiter == 7
    with pytest.raises(SceneError, match=r"^linear_rtol: given twice"):
        make_integrator("implicit_euler", model, linear_rtol=1e-9, solver_options={"rtol": 1e-8})
    assert make_integrator("implicit_euler", model, solver="cg", linear_rtol=None).solver.rtol == DEFAULT_RTOL


def test_linear_rtol_of_an_integrator_without_a_solver_is_named_unused():
    model = load_scene(SCENE).model
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        make_integrator("symplectic_euler", model, linear_rtol=1e-9)
    assert [str(w.message) for w in caught if issubclass(w.category, UnusedOptionWarning)] == [
        "symplectic_euler does not use the option(s) linear_rtol; ignored"]


def test_names_are_checked_by_one_function():
    """The run configuration, the factories and the assembler check names with check_choice: one message."""
    from springsim.forces import JACOBIAN_MODES

    assert check_choice("spd", JACOBIAN_MODES, param="jacobian", what="jacobian mode") == "spd"
    for bad in ("wrong", 3, ["exact"], None):
        with pytest.raises(SceneError, match=r"^p: unknown thing .*; choose one of exact, symmetric, spd, mixed$"):
            check_choice(bad, JACOBIAN_MODES, param="p", what="thing")
    with pytest.raises(SceneError, match="^solver.jacobian: unknown jacobian mode 'wrong'; choose one of exact"):
        load_scene(SCENE.replace("steps: 2", "steps: 2, jacobian: wrong"))
    from springsim.assembly import SystemAssembler
    from springsim.forces import make_force_terms

    model = load_scene(SCENE).model
    asm = SystemAssembler(model, make_force_terms(model))
    with pytest.raises(SceneError, match="^jacobian: unknown jacobian mode 'bogus'; choose one of exact"):
        asm.assemble(model.particle_q, model.particle_qd, 1.0, 1.0, "bogus")


def test_unused_options_of_explicit_integrators_are_derived():
    """The explicit integrators ignore exactly the keyword options ImplicitIntegrator adds to Integrator's, derived
    from the signatures (an option added to the implicit integrators is known to the explicit ones at once)."""
    from springsim.integrators import IMPLICIT_OPTIONS, INTEGRATORS, ImplicitIntegrator, Integrator

    own = set(inspect.signature(Integrator.__init__).parameters)
    implicit = {name for name, p in inspect.signature(ImplicitIntegrator.__init__).parameters.items()
                if p.kind is p.KEYWORD_ONLY}
    assert IMPLICIT_OPTIONS == implicit - own
    assert {"solver", "solver_options", "jacobian", "newton_tol", "stage_solver", "forcing"} <= IMPLICIT_OPTIONS
    assert not IMPLICIT_OPTIONS & {"system", "terms", "force_kernels"}
    for name, cls in INTEGRATORS.items():
        if cls.implicit:
            assert cls.unused_options < IMPLICIT_OPTIONS, name
        else:
            assert cls.unused_options == IMPLICIT_OPTIONS, name
