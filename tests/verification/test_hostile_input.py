"""Hostile input and faults: every class ends in one clear line (exit 2 for bad input, 1 for a failed run, 130 for
an interrupt), in bounded time and memory, with computed frames kept and output files never half-written.

Classes (docs/robustness.md, "Guarantees"): the scene loader, command-line options, output files, adaptive runs
that hit a solver failure, the Python API at its boundary, reproducibility of the solvers, the BLAS thread policy.
"""

from __future__ import annotations

import errno
import os
import stat
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from helpers import one_line_error, run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import springsim
from springsim import cli
from springsim._runtime import memory
from springsim.errors import SceneError, SceneTypeError, SimulationError, SimulationInterrupted
from springsim.integrators import make_integrator
from springsim.linsolve import LINEAR_SOLVERS, make_linear_solver
from springsim.model.builder import ModelBuilder
from springsim.run.adaptive import simulate_adaptive
from springsim.run.driver import Trajectory, save_npz_atomic, simulate
from springsim.scene import load_scene, yaml_io

ROOT = Path(__file__).resolve().parents[2]
SPRING = str(ROOT / "scenes" / "spring.yaml")
HEAD = "solver: {type: implicit_euler, timestep: 0.01}\n"


_main, _one_line_error = run_cli, one_line_error


def _scene_error(text: str) -> str:
    with pytest.raises(SceneError) as e:
        load_scene(text)
    msg = str(e.value)
    assert "\n" not in msg and len(msg) < 400
    return msg


# -- the scene loader ---------------------------------------------------------------------------------------------
def _alias_bomb(levels: int, fan: int = 10) -> str:
    lines = [HEAD.strip(), "x-a0: &a0 [" + ", ".join(["1"] * fan) + "]"]
    for k in range(1, levels):
        lines.append(f"x-a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * fan) + "]")
    lines.append(f"particles: [{{pos: *a{levels - 1}, mass: 1}}]")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("levels", [7, 9, 30])
def test_alias_bomb_is_refused_quickly(levels):
    """A few hundred bytes whose aliases expand to 1e7 ... 1e30 nodes are refused in bounded time, naming the line."""
    t0 = time.perf_counter()
    msg = _scene_error(_alias_bomb(levels))
    assert "aliases expand the document" in msg and "line" in msg
    assert time.perf_counter() - t0 < 5.0


def test_modest_aliases_are_fine():
    """Honest aliases (a shared velocity, a merged particle template) still load."""
    text = HEAD + "x-zero: &z [0, 0, 0]\nx-base: &b {mass: 1, vel: *z}\nparticles:\n" + "".join(
        f"  - {{<<: *b, pos: [{k}, 0, 0]}}\n" for k in range(50))
    assert load_scene(text).model.particle_count == 50


@pytest.mark.parametrize("text", [
    HEAD + "x-deep: " + "[" * 100 + "]" * 100 + "\n",
    HEAD + "x-deep: " + "[" * 200000 + "]" * 200000 + "\n",
    HEAD + "x-deep:\n" + "".join("  " * k + "- \n" for k in range(1, 3000)),
    HEAD + "x-deep: " + "{a: " * 500 + "1" + "}" * 500 + "\n",
], ids=["flow100", "flow200000", "block3000", "mapping500"])
def test_deep_nesting_is_an_error_not_a_crash(text):
    """Deeply nested documents (which crash the C parser's composer) are refused before composing."""
    msg = _scene_error(text)
    assert "nest" in msg


@pytest.mark.parametrize("text, key", [
    (HEAD + "particles:\n  - {pos: [0, 0, 0], mass: 1, mass: 2}\n", "mass"),
    (HEAD + "solver: {type: midpoint, timestep: 0.1}\nparticles: [{pos: [0, 0, 0], mass: 1}]\n", "solver"),
    (HEAD + "particles:\n  - pos: [0, 0, 0]\n    mass: 1\n    fixed: true\n    fixed: false\n", "fixed"),
    ("solver:\n  type: implicit_euler\n  timestep: 0.01\n  timestep: 0.02\nparticles: [{pos: [0,0,0], mass: 1}]\n",
     "timestep"),
])
def test_duplicate_keys_are_refused(text, key):
    """A key given twice in one mapping (the second silently won before) is an error naming the key and line."""
    msg = _scene_error(text)
    assert f"duplicate key '{key}'" in msg and "line" in msg


def test_merge_keys_may_be_overridden():
    """Keys brought in by a merge (<<) may be overridden: that is YAML, not a duplicate."""
    s = load_scene(HEAD + "x-b: &b {mass: 1, pos: [0, 0, 0]}\nparticles:\n  - {<<: *b, mass: 2}\n")
    assert s.model.particle_mass[0] == 2.0


@pytest.mark.parametrize("text", [
    HEAD + "particles: [{pos: [0, 0, 0], mass: " + "9" * 5000 + "}]\n",
    HEAD + "particles: [{pos: [0, 0, 0], mass: " + "9" * 400 + "}]\n",
    "solver: {type: implicit_euler, timestep: 0.01, steps: " + "9" * 4000 + "}\nparticles: [{pos: [0,0,0], mass: 1}]\n",
    HEAD + "cloth: {nx: " + "9" * 3000 + ", ny: " + "9" * 3000 + "}\n",
    HEAD + "particles: [{pos: [0, 0, 0], mass: 1}]\nsprings: [{particle_ids: [0, " + "9" * 2000 + "], stiffness: 1}]\n",
], ids=["int5000", "int400", "steps4000", "cloth3000", "ids2000"])
def test_huge_integers_are_errors(text):
    """Integers with thousands of digits are one-line errors (never a conversion traceback or a huge message)."""
    _scene_error(text)


def test_huge_generated_cloth_is_refused_by_memory(monkeypatch):
    """A generator block that would need more memory than is available is refused before allocating anything."""
    monkeypatch.setattr(memory, "available_memory", lambda: 2**30)
    msg = _scene_error(HEAD + "cloth: {nx: 2000, ny: 2000}\n")
    assert "4000000 particles" in msg and "GiB" in msg
    msg = _scene_error(HEAD + "benchmark_cloth: {n: 100000}\n")  # above MAX_GENERATED_PARTICLES
    assert "limit" in msg
    # not built (a distributed run generates a share per process): checked per process where the count is known
    scene = yaml_io.load_scene(HEAD + "cloth: {nx: 2000, ny: 2000}\n", build=False)
    assert scene.model is None and scene.generator["grid"]["nx"] == 2000
    with pytest.raises(SceneError, match=r"^cloth: generator blocks would create 4000000 particles \(2 processes"):
        yaml_io.check_generated_memory("cloth", 4_000_000, 2)
    yaml_io.check_generated_memory("cloth", 4_000_000, 8)  # 1/8 of them fits


def test_memory_error_while_building_is_a_scene_error(monkeypatch):
    """A MemoryError while the model is built ends in a one-line SceneError."""
    def boom(*a, **k):
        raise MemoryError

    monkeypatch.setattr(yaml_io.ModelBuilder, "finalize", boom)
    assert "does not fit in memory" in _scene_error(HEAD + "particles: [{pos: [0, 0, 0], mass: 1}]\n")


def test_files_that_are_not_scene_files(tmp_path, monkeypatch, capsys):
    """Devices, FIFOs, directories, endless and oversized files and non-UTF-8 bytes: one line, exit 2, at once."""
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    big = tmp_path / "big.yaml"
    big.write_text(HEAD + "particles: [{pos: [0, 0, 0], mass: 1}]\n" + "#" * 2000 + "\n")
    binary = tmp_path / "bin.yaml"
    binary.write_bytes(b"solver: \xff\xfe\n")
    monkeypatch.setattr(yaml_io, "MAX_SCENE_BYTES", 1000)
    for path, fragment in ((fifo, "not a regular file"), ("/dev/zero", "not a regular file"),
                           ("/dev/null", "not a regular file"), (tmp_path, "is a directory"),
                           (tmp_path / "none.yaml", "no such file"), (big, "more than the limit"),
                           (binary, "not UTF-8")):
        t0 = time.perf_counter()
        line = _one_line_error(capsys, "run", path)
        assert fragment in line and time.perf_counter() - t0 < 5.0


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(depth=st.integers(1, 120), fan=st.integers(1, 12), levels=st.integers(1, 12),
       duplicate=st.booleans())
def test_generated_hostile_documents(depth, fan, levels, duplicate):
    """Generated documents mixing nesting, alias fan-out and duplicate keys either load or raise a one-line
    SceneError, in bounded time."""
    lines = [HEAD.strip(), "x-a0: &a0 1"]
    for k in range(1, levels):
        lines.append(f"x-a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * fan) + "]")
    lines.append(f"x-nest: {'[' * depth}*a{levels - 1}{']' * depth}")
    lines.append("particles: [{pos: [0, 0, 0], mass: 1" + (", mass: 2" if duplicate else "") + "}]")
    t0 = time.perf_counter()
    try:
        load_scene("\n".join(lines) + "\n")
    except SceneError as e:
        assert "\n" not in str(e) and len(str(e)) < 400
    assert time.perf_counter() - t0 < 5.0


# -- command-line options -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, fragment", [
    (["--duration", "1e300", "--dt", "1e-300"], "needs more than"),
    (["--duration", "1e308", "--dt", "1e-308"], "needs more than"),
    (["--steps", "9" * 50], "--steps"),
    (["--steps", "99999999999999999999"], "must be <="),
    (["--dt", "inf"], "--dt"),
    (["--dt", "-1"], "--dt"),
    (["--dt", "nan"], "--dt"),
    (["--frame-every", "0"], "--frame-every"),
    (["--newton-maxiter", "10000000"], "--newton-maxiter"),
    (["--integrator", "nope"], "invalid choice: 'nope'"),
])
def test_bad_run_options_are_one_line(capsys, argv, fragment):
    """Overflowing or invalid option values: one line naming the option, exit 2."""
    assert fragment in _one_line_error(capsys, "run", SPRING, *argv)


def test_corrupt_trajectories(tmp_path, capsys):
    """Truncated, corrupt, pickled and mismatched .npz files given to export and render: one line, exit 2."""
    good = tmp_path / "good.npz"
    assert cli.main(["run", SPRING, "--steps", "5", "--out", str(good), "--quiet"]) == 0
    data = good.read_bytes()
    (tmp_path / "trunc.npz").write_bytes(data[: len(data) // 2])
    (tmp_path / "noise.npz").write_bytes(np.random.default_rng(11).bytes(400))
    np.savez(tmp_path / "pickled.npz", t=np.array([0.0]), q=np.array([object()], dtype=object))
    np.savez(tmp_path / "shapes.npz", t=np.zeros(3), q=np.zeros((2, 2, 3)))
    np.savez(tmp_path / "empty.npz")
    for name in ("trunc", "noise", "pickled", "shapes", "empty"):
        f = tmp_path / f"{name}.npz"
        assert str(f) in _one_line_error(capsys, "export", f, SPRING, "--out", tmp_path / "out")
        assert str(f) in _one_line_error(capsys, "render", f, "--scene", SPRING, "--out", tmp_path / "x.png")


def test_interrupt_during_start_up(capsys, monkeypatch):
    """Ctrl-C while the commands are imported (start-up) prints one line and exits 130."""
    def interrupted(cmd):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_resolve", interrupted)
    assert _one_line_error(capsys, "run", SPRING, code=130) == "springsim: interrupted"


def test_cli_module_imports_no_numerics():
    """Importing the command line imports neither numpy nor scipy, so start-up is short and interruptible."""
    import subprocess

    code = "import sys, springsim.cli; sys.exit(int(any(m in sys.modules for m in ('numpy', 'scipy'))))"
    assert subprocess.run([sys.executable, "-c", code], timeout=120).returncode == 0


# -- output files -------------------------------------------------------------------------------------------------
def test_out_must_be_a_regular_file(tmp_path, capsys):
    """--out naming a FIFO, a device, a directory or a missing directory fails before the run, leaving it as it was."""
    fifo = tmp_path / "f.npz"
    os.mkfifo(fifo)
    for out, fragment in ((fifo, "not a regular file"), ("/dev/null", "not a regular file"),
                          (tmp_path, "is a directory"), (tmp_path / "no" / "x.npz", "does not exist")):
        assert fragment in _one_line_error(capsys, "run", SPRING, "--out", out)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_out_follows_symlinks_and_keeps_modes(tmp_path, capsys):
    """A symlinked --out replaces the link's target and keeps the link; a new file gets 0666 less the umask; a
    replaced file keeps its mode."""
    target = tmp_path / "target.npz"
    target.write_bytes(b"old")
    link = tmp_path / "link.npz"
    link.symlink_to(target)
    assert cli.main(["run", SPRING, "--steps", "3", "--out", str(link), "--quiet"]) == 0
    assert link.is_symlink() and Trajectory.load(target).frame_count == 4
    old = os.umask(0o027)
    try:
        new = tmp_path / "new.npz"
        assert cli.main(["run", SPRING, "--steps", "3", "--out", str(new), "--quiet"]) == 0
        assert stat.S_IMODE(os.stat(new).st_mode) == 0o640
        os.chmod(new, 0o604)
        assert cli.main(["run", SPRING, "--steps", "3", "--out", str(new), "--quiet"]) == 0
        assert stat.S_IMODE(os.stat(new).st_mode) == 0o604
    finally:
        os.umask(old)


def test_unwritable_out_fails_before_the_run(tmp_path, capsys, monkeypatch):
    """A directory that does not take new files fails --out at once, before any step is computed."""
    steps = []
    real_simulate = springsim.run.driver.simulate
    monkeypatch.setattr(springsim.run.driver, "simulate", lambda *a, **k: steps.append(1) or real_simulate(*a, **k))
    real_open = os.open

    def refuse(path, *a, **k):  # the directory refuses new files (root ignores permission bits: inject it)
        if str(tmp_path) in os.fspath(path):
            raise PermissionError(errno.EACCES, "Permission denied")
        return real_open(path, *a, **k)

    monkeypatch.setattr(os, "open", refuse)
    assert "cannot write" in _one_line_error(capsys, "run", SPRING, "--out", tmp_path / "x.npz")
    assert steps == []


def test_full_disk_at_the_end_keeps_the_frames(tmp_path, capsys, monkeypatch):
    """When writing --out fails after the run (disk full), the frames go to a rescue file named on stderr, exit 1;
    the previous --out file is untouched."""
    out = tmp_path / "out.npz"
    out.write_bytes(b"previous")
    real = np.savez
    calls = []

    def savez(fh, **arrays):
        calls.append(1)
        if len(calls) == 1:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(fh, **arrays)

    monkeypatch.setattr(np, "savez", savez)
    code, _, err = _main(capsys, "run", SPRING, "--steps", "4", "--out", out, "--quiet")
    assert code == 1 and "No space left on device" in err and "Traceback" not in err
    rescue = Path(err.split(" to ")[-1].split(" instead")[0])
    assert Trajectory.load(rescue).frame_count == 5
    assert out.read_bytes() == b"previous" and not list(tmp_path.glob(".*"))
    rescue.unlink()


def test_atomic_writer_refuses_special_files(tmp_path):
    """save_npz_atomic never replaces a FIFO or a device with a regular file."""
    fifo = tmp_path / "f.npz"
    os.mkfifo(fifo)
    for target in (fifo, Path("/dev/null")):
        with pytest.raises(springsim.SpringsimError, match="not a regular file"):
            save_npz_atomic(target, t=np.zeros(1))
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


# -- adaptive runs that hit a solver failure ------------------------------------------------------------------------
def _singular_pair():
    """Two particles at the same place with a gravitational softening so small that every implicit matrix is
    singular to working precision (precision loss ~1e7): every solve fails."""
    b = ModelBuilder()
    b.add_particles([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], None, [1.0, 0.5, 1.0])
    b.add_gravitational(0, 1, 1.0, softening=1e-9)
    return b.finalize()


def test_adaptive_solver_failure_is_a_simulation_error_with_frames():
    """An adaptive run whose solves keep failing retries smaller steps, then stops with SimulationError (not an
    input error), naming the time, with the frames so far."""
    m = _singular_pair()
    with pytest.raises(SimulationError) as e:
        simulate_adaptive(m, "tr_bdf2", 0.1, frame_dt=0.01, h_min=1e-6)
    assert not isinstance(e.value, SceneError)
    assert "h = h_min" in str(e.value) and ("singular" in str(e.value) or "ill-conditioned" in str(e.value))
    assert e.value.trajectory is not None and e.value.trajectory.frame_count >= 1


def test_adaptive_solver_failure_in_the_cli_exits_1_and_saves(tmp_path, capsys):
    """The same through the command line: exit 1 (not 2), the error and the saved frames on stderr."""
    scene = tmp_path / "pair.yaml"
    scene.write_text("solver: {type: tr_bdf2, timestep: 0.01, steps: 10}\n"
                     "particles: [{pos: [0, 0, 0], mass: 1}, {pos: [0, 0, 0], mass: 0.5}]\n"
                     "gravitational: [{particle_ids: [0, 1], G: 1, softening: 1.0e-9}]\n")
    out = tmp_path / "pair.npz"
    code, _, err = _main(capsys, "run", scene, "--time-rtol", "1e-3", "--out", out, "--quiet")
    assert code == 1 and "springsim: error:" in err and "Traceback" not in err
    assert f"to {out}" in err and Trajectory.load(out).frame_count >= 1


# -- the Python API at its boundary ------------------------------------------------------------------------------
def _chain():
    b = ModelBuilder()
    b.add_particles([[0, 0, 0], [1, 0, 0], [2, 0, 0]], None, 1.0, fixed=[True, False, False])
    b.add_springs([[0, 1], [1, 2]], 100.0)
    return b.finalize()


def test_integer_initial_state_is_converted_not_truncated():
    """An integer initial state gives the same run as its float twin (it used to be truncated step by step)."""
    m = _chain()
    qi = springsim.State(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 1]]), np.zeros((3, 3), dtype=int))
    qf = springsim.State(qi.particle_q.astype(float), qi.particle_qd.astype(float))
    a = simulate(m, make_integrator("symplectic_euler", m), 0.01, 10, state=qi)
    b = simulate(m, make_integrator("symplectic_euler", m), 0.01, 10, state=qf)
    np.testing.assert_array_equal(a.q, b.q)
    assert a.q.dtype == np.float64 and qi.particle_q.dtype.kind == "i"  # the caller's arrays are untouched


@pytest.mark.parametrize("make_state, exc, fragment", [
    (lambda m: springsim.State(np.zeros((2, 3)), np.zeros((3, 3))), ValueError, "state.particle_q must have shape"),
    (lambda m: springsim.State(np.zeros((3, 3)), np.zeros(9)), ValueError, "state.particle_qd must have shape"),
    (lambda m: springsim.State(np.full((3, 3), "a"), np.zeros((3, 3))), TypeError, "state.particle_q must be numeric"),
    (lambda m: (1, 2), TypeError, "state must be a springsim State"),
])
def test_bad_states_are_named(make_state, exc, fragment):
    """Wrong shapes and types of the initial state raise ValueError/TypeError naming the parameter."""
    m = _chain()
    with pytest.raises(exc, match=fragment):
        simulate(m, make_integrator("implicit_euler", m), 0.01, 1, state=make_state(m))


def test_integrator_for_another_model_is_refused():
    """Passing an integrator built for another model is a ValueError saying so (it used to fail deep in numpy)."""
    m, other = _chain(), ModelBuilder().finalize()
    with pytest.raises(ValueError, match="built for another model"):
        simulate(m, make_integrator("implicit_euler", other), 0.01, 1)
    with pytest.raises(TypeError, match="integrator must be"):
        simulate(m, "implicit_euler", 0.01, 1)


@pytest.mark.parametrize("call, path", [
    (lambda b: b.add_particle((0, 0, 0), fixed="false"), "particles.fixed"),
    (lambda b: b.add_particles([[0, 0, 0]], fixed=[0.5]), "particles.fixed"),
    (lambda b: b.add_particle((0, 0, 0), mass=True), "particles.mass"),
    (lambda b: b.add_particle((0, 0, 0), mass="2"), "particles.mass"),
    (lambda b: b.add_particle(("0", 0, 0)), "particles.pos"),
    (lambda b: b.add_particle((0, 0, 0), drag=[True]), "particles.drag"),
    (lambda b: b.add_springs([[0, 1]], ke="100"), "springs.stiffness"),
    (lambda b: b.add_gravitational(0, 1, G=False), "gravitational.G"),
])
def test_builder_refuses_strings_and_booleans_as_numbers(call, path):
    """The builder converts at the boundary: strings and booleans are not numbers, "false" is not a flag
    (SceneTypeError, a TypeError naming the parameter)."""
    b = ModelBuilder()
    b.add_particles(np.eye(2, 3), None, 1.0)
    with pytest.raises(SceneTypeError, match=rf"^{path}: ") as e:
        call(b)
    assert isinstance(e.value, TypeError)


@pytest.mark.parametrize("kw", [dict(gravity="9.81"), dict(gravity=True), dict(pair_epsilon="1e-9"),
                                dict(up_axis=True)])
def test_builder_options_are_checked(kw):
    """Builder options of the wrong type are refused at finalize with the option's name."""
    with pytest.raises(SceneError, match=list(kw)[0] if "gravity" not in kw else "solver.gravity"):
        ModelBuilder(**kw).finalize()


def test_interrupt_is_not_a_simulation_error():
    """SimulationInterrupted is exported, is a KeyboardInterrupt, and `except SimulationError` does not catch it."""
    m = _chain()

    def progress(k, n):
        if k == 3:
            raise KeyboardInterrupt

    with pytest.raises(springsim.SimulationInterrupted) as e:
        try:
            simulate(m, make_integrator("symplectic_euler", m), 0.01, 10, progress=progress)
        except SimulationError:  # user code like this must not swallow Ctrl-C
            pytest.fail("SimulationError caught an interrupt")
    assert springsim.SimulationInterrupted is SimulationInterrupted and e.value.trajectory.frame_count == 4
    assert not isinstance(e.value, Exception)


# -- reproducibility --------------------------------------------------------------------------------------------------
def _spd_and_nonsymmetric():
    from springsim.assembly import SystemAssembler
    from springsim.forces import make_force_terms
    from springsim.scene.gallery import benchmark_cloth

    m = benchmark_cloth(24, kd=1.0)
    rng = np.random.default_rng(4242)
    q = m.particle_q + rng.normal(scale=1e-3, size=m.particle_q.shape)
    qd = rng.normal(size=q.shape)
    asm = SystemAssembler(m, make_force_terms(m))
    b = rng.normal(size=asm.dof_count)
    return [(asm.assemble(q, qd, 1e-4, 1e-2, mode).bsr.copy(), b) for mode in ("spd", "exact")]


@pytest.mark.parametrize("name", sorted(LINEAR_SOLVERS))
def test_solvers_are_deterministic_and_leave_global_random_state_alone(name):
    """Every solver gives bitwise the same answer for the same input, in one process and across fresh solver
    instances, and never touches NumPy's global random state (pyamg's setup draws from it)."""
    for A, b in _spd_and_nonsymmetric():
        np.random.seed(777)
        before = np.random.get_state()[1].copy()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            x1 = make_linear_solver(name).solve(A, b).x
            x2 = make_linear_solver(name).solve(A, b).x
        np.testing.assert_array_equal(x1, x2)
        np.testing.assert_array_equal(np.random.get_state()[1], before)


# -- the BLAS thread policy -----------------------------------------------------------------------------------------
def test_solves_run_with_one_blas_thread():
    """Inside a solve every loaded BLAS runs one thread; the caller's setting is restored afterwards."""
    threadpoolctl = pytest.importorskip("threadpoolctl")  # a test extra: CI always has it
    from springsim._runtime import threads as _threads

    seen = []
    solver = make_linear_solver("dense")
    real = solver._solve

    def spy(A, b, x0, rtol):
        seen.append([i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"])
        return real(A, b, x0, rtol)

    solver._solve = spy
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        solver.solve(np.eye(6) * 2.0, np.ones(6))
        after = [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]
    assert seen and all(n == 1 for n in seen[0])
    assert all(n == 2 for n in after)
    assert _threads.have_threadpoolctl()


def test_thread_policy_is_a_no_op_without_threadpoolctl(monkeypatch):
    """Without threadpoolctl (an optional extra) solves work the same, with the environment's thread setting."""
    from springsim._runtime import threads as _threads

    monkeypatch.setitem(sys.modules, "threadpoolctl", None)
    monkeypatch.setattr(_threads, "_controller", None)
    assert not _threads.have_threadpoolctl()
    res = make_linear_solver("direct").solve(np.eye(6) * 2.0, np.ones(6))
    assert res.converged and np.allclose(res.x, 0.5)
    monkeypatch.setattr(_threads, "_controller", None)  # let the next solve find threadpoolctl again
