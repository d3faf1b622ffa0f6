"""The ``springsim`` command line: run, overrides, --out, exit codes and one-line errors."""

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import PENDULUM_YAML

from springsim import cli
from springsim.errors import SimulationError

ROOT = Path(__file__).resolve().parents[2]
SPRING = str(ROOT / "scenes" / "spring.yaml")

SCENE = PENDULUM_YAML


@pytest.fixture
def scene_file(tmp_path):
    """A two-particle spring scene written to a temporary file."""
    f = tmp_path / "s.yaml"
    f.write_text(SCENE)
    return f


def _run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_run_prints_summary(capsys, scene_file):
    """``run`` exits 0 and prints the summary rows on stdout, nothing on stderr (not a tty)."""
    code, out, err = _run(capsys, "run", scene_file)
    assert code == 0 and err == ""
    for key in ("scene:", "particles:", "2 (1 free, 1 fixed)", "springs:", "gravitational pairs:", "dofs:",
                "implicit_euler (linear solver auto -> direct: 3 DOFs <= 4000, minimize stages, jacobian mixed)", "steps:", "5 x dt = 0.01 s",
                "simulated time:", "wall time:", "(CPU ", "time per step:", "assembly per step:", "other per step:",
                "Newton iterations:", "linear iterations:", "failed steps:", "solver fallbacks:",
                "max linear residual:",
                "max precision loss:"):
        assert key in out


def test_out_npz_and_overrides(capsys, scene_file, tmp_path):
    """--out writes t, q, qd with frame 0 the initial state; --steps/--dt/--frame-every override the scene."""
    out_file = tmp_path / "traj.npz"
    code, out, _ = _run(capsys, "run", scene_file, "--steps", 7, "--dt", 0.02, "--frame-every", 3,
                        "--integrator", "symplectic_euler", "--out", out_file)
    assert code == 0
    with np.load(out_file) as z:
        t, q, qd = z["t"], z["q"], z["qd"]
    import hashlib

    from springsim.run.driver import Trajectory

    meta = Trajectory.load(out_file).meta
    assert meta["scene_sha256"] == hashlib.sha256(scene_file.read_bytes()).hexdigest()
    assert meta["integrator"] == "symplectic_euler" and meta["dt"] == 0.02 and meta["frame_every"] == 3
    assert meta["run_options"]["integrator"] == "symplectic_euler"
    np.testing.assert_allclose(t, [0.0, 0.06, 0.12, 0.14])
    assert q.shape == (4, 2, 3) and qd.shape == (4, 2, 3)
    np.testing.assert_array_equal(q[0], [[0, 0, 1], [0, 0, 0]])
    np.testing.assert_array_equal(q[:, 0], np.tile([0, 0, 1], (4, 1)))
    assert "symplectic_euler" in out and "7 x dt = 0.02 s" in out and "(4 frames)" in out


def test_solver_options_override(capsys, scene_file):
    """--solver/--jacobian/--newton-tol/--newton-maxiter/--rtol reach the implicit integrator."""
    code, out, _ = _run(capsys, "run", scene_file, "--solver", "dense", "--jacobian", "symmetric",
                        "--newton-tol", "1e-9", "--newton-maxiter", 3, "--rtol", "1e-8", "--quiet")
    assert code == 0 and out == ""
    code, out, _ = _run(capsys, "run", scene_file, "--solver", "dense", "--jacobian", "symmetric", "--steps", 1)
    assert "linear solver dense, residual stages, jacobian symmetric" in out


def test_duration_and_default_steps(capsys, tmp_path):
    """--duration sets ceil(T/dt) steps; without any step count the default (100) is used."""
    f = tmp_path / "nosteps.yaml"
    f.write_text(SCENE.replace(", steps: 5", ""))
    code, out, _ = _run(capsys, "run", f, "--duration", 0.035)
    assert code == 0 and "4 x dt" in out
    code, out, _ = _run(capsys, "run", f, "--integrator", "explicit_euler")
    assert code == 0 and "100 x dt" in out


@pytest.mark.parametrize("argv, fragment", [
    (["run", "missing.yaml"], "missing.yaml: no such file"),
    (["run", "{scene}", "--integrator", "nope"], "argument --integrator: invalid choice: 'nope' (choose from"),
    (["run", "{scene}", "--solver", "magic"], "argument --solver: invalid choice: 'magic'"),
    (["run", "{scene}", "--jacobian", "bad"], "argument --jacobian: invalid choice: 'bad'"),
    (["run", "{bad}"], "springs[0].stiffness: must be >= 0, got -1"),
    (["run", "{syntax}"], "YAML syntax error at line"),
    (["run", "{scene}", "--out", "{tmp}/no/such/dir/x.npz"], "does not exist"),
])
def test_user_errors_exit_2_one_line(capsys, scene_file, tmp_path, argv, fragment):
    """User errors print one line 'springsim: error: ...' on stderr, no traceback, and exit 2."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(SCENE.replace("stiffness: 100", "stiffness: -1"))
    syntax = tmp_path / "syntax.yaml"
    syntax.write_text("solver: {type: x\n  particles: [")
    argv = [a.format(scene=scene_file, bad=bad, syntax=syntax, tmp=tmp_path) for a in argv]
    code, out, err = _run(capsys, *argv)
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(("springsim: error: ", "springsim run: error: ")), err
    assert fragment in lines[0], err
    assert "Traceback" not in err


def test_bad_option_values_exit_2(capsys, scene_file):
    """Invalid option values (negative dt, non-integer steps) are argparse usage errors with status 2."""
    for argv in (["--dt", "-1"], ["--steps", "x"], ["--frame-every", "0"], ["--steps", "2", "--duration", "1"]):
        code, _, err = _run(capsys, "run", scene_file, *argv)
        assert code == 2 and "Traceback" not in err


def _fake_simulate(exc_type):
    def fake(model, integrator, dt, steps, **kwargs):
        from springsim.run.driver import Trajectory

        q0 = model.particle_q[None].copy()
        traj = Trajectory(np.array([0.0]), q0, np.zeros_like(q0))
        raise exc_type("stopped at step 3", traj, step=3)
    return fake


def test_blow_up_saves_finite_frames(capsys, tmp_path):
    """A blow-up prints the message, saves the finite frames to --out, says so and exits 1."""
    f = tmp_path / "stiff.yaml"
    f.write_text(SCENE.replace("implicit_euler", "explicit_euler").replace("stiffness: 100", "stiffness: 1.0e9")
                 .replace("steps: 5", "steps: 400"))
    out_file = tmp_path / "blow.npz"
    code, _, err = _run(capsys, "run", f, "--out", out_file)
    assert code == 1 and "blew up" in err and f"to {out_file}" in err and "Traceback" not in err
    with np.load(out_file) as z:
        assert np.all(np.isfinite(z["q"])) and z["q"].shape[0] == z["t"].shape[0] >= 1


def test_interrupt_saves_frames_exit_130(capsys, scene_file, tmp_path, monkeypatch):
    """Ctrl-C (SimulationInterrupted) saves the frames so far, says so and exits 130."""
    from springsim.run import driver

    monkeypatch.setattr(driver, "simulate", _fake_simulate(driver.SimulationInterrupted))
    out_file = tmp_path / "int.npz"
    code, _, err = _run(capsys, "run", scene_file, "--out", out_file)
    assert code == 130 and "interrupted" in err and "saved 1 finite frame" in err
    assert out_file.exists()
    monkeypatch.setattr(driver, "simulate", _fake_simulate(SimulationError))
    code, _, err = _run(capsys, "run", scene_file)
    assert code == 1 and "stopped at step 3" in err


def test_command_registry(capsys):
    """A command added to COMMANDS (one line) gets its own subparser and exit status."""
    seen = {}
    cmd = cli.Command(lambda p: p.add_argument("x"), lambda a: seen.setdefault("x", a.x) and 0, "echo")
    cli.COMMANDS["echo-test"] = cmd
    try:
        assert cli.main(["echo-test", "hello"]) == 0 and seen == {"x": "hello"}
    finally:
        del cli.COMMANDS["echo-test"]


def test_python_dash_m_entry_point(tmp_path):
    """``python -m springsim run`` works as a real process: exit 0 with a summary, exit 2 on a bad scene."""
    ok = subprocess.run([sys.executable, "-m", "springsim", "run", SPRING, "--steps", "3"],
                        capture_output=True, text=True, timeout=120, cwd=tmp_path)  # not the checkout's springsim/
    assert ok.returncode == 0 and "particles:" in ok.stdout, ok.stderr
    bad = tmp_path / "bad.yaml"
    bad.write_text("solver: [")
    err = subprocess.run([sys.executable, "-m", "springsim", "run", str(bad)], capture_output=True, text=True,
                         timeout=120, cwd=tmp_path)
    assert err.returncode == 2 and err.stderr.count("\n") == 1 and "Traceback" not in err.stderr


def test_newton_nonconvergence_is_one_line_and_the_exit_status(capsys, scene_file):
    """Steps that fail after their substep retakes give one summary line on stderr (not a warning per step): an
    error and exit status 1, or with ``--keep-going`` a warning and 0; the frames are kept either way."""
    argv = ["run", scene_file, "--stage-solver", "residual", "--newton-maxiter", 1, "--newton-tol", "1e-14"]
    for extra, status, kind in (([], 1, "error"), (["--keep-going"], 0, "warning")):
        code, out, err = _run(capsys, *argv, *extra)
        assert code == status and re.search(r"failed steps:\s+5 \(Newton 5, linear solves 0, ill-conditioned 0\)", out)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"springsim: {kind}: 5 of 5 step(s) did not meet their "
                                                       "criteria (first: Newton did not converge in 1 iterations")


def test_options_the_stage_rule_does_not_use_are_reported(capsys, scene_file):
    """``--newton-tol`` with minimize stages (the default) has no effect: one warning line names it."""
    code, _, err = _run(capsys, "run", scene_file, "--newton-tol", "1e-9", "--quiet")
    assert code == 0 and err.strip() == "springsim: warning: implicit_euler does not use newton_tol; ignored"


def test_adaptive_run_and_max_step(capsys, scene_file):
    """``--time-rtol`` runs adaptive steps; ``--max-step`` caps them (and is rejected when not > 0)."""
    import re

    def largest_step(*extra, integrator="tr_bdf2"):
        code, out, _ = _run(capsys, "run", scene_file, "--integrator", integrator, "--time-rtol", 1e-3,
                            "--steps", 20, "--dt", 0.05, *extra)
        assert code == 0, out
        lo, hi = map(float, re.search(r"h in \[([^,]+), ([^\]]+)\] s", out).groups())
        assert re.search(r"steps: +\d+ adaptive", out) and lo <= hi
        return hi

    free = largest_step()
    assert free > 0.02  # this smooth scene lets the controller grow past the cap tried below
    assert largest_step("--max-step", 0.02) <= 0.02 + 1e-12
    assert largest_step("--max-step", 0.02, integrator="energy_momentum") <= 0.02 + 1e-12  # step doubling
    code, _, err = _run(capsys, "run", scene_file, "--time-rtol", 1e-3, "--max-step", 0)
    assert code == 2 and "--max-step" in err
