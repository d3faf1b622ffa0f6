"""The simulation driver: blow-up detection, wrapped solver errors, interrupts, atomic ``.npz`` writes."""

import os

import numpy as np
import pytest

from springsim.errors import SimulationError, SolverError, SpringsimError
from springsim.integrators import Integrator, StepStats, make_integrator
from springsim.model.builder import ModelBuilder
from springsim.run.driver import SimulationInterrupted, Trajectory, save_npz_atomic, simulate
from springsim.run.energy import EnergyBound


def _stiff_spring(ke=1e8):
    """One free particle (index 1) on a very stiff spring to a fixed particle (index 0)."""
    b = ModelBuilder(gravity=0.0)
    b.add_particle((0.0, 0.0, 0.0), mass=1.0, fixed=True)
    b.add_particle((1.001, 0.0, 0.0), vel=(0.0, 0.5, 0.0), mass=1.0)
    b.add_spring(0, 1, ke, 0.0, 1.0)
    return b.finalize()


def _chain(n=4, seed=5):
    """A small hanging chain with random initial velocities."""
    rng = np.random.default_rng(seed)
    b = ModelBuilder()
    pos = np.column_stack([np.arange(n) * 0.1, np.zeros(n), np.zeros(n)])
    b.add_particles(pos, rng.normal(size=(n, 3)) * 0.1, 0.1, fixed=np.arange(n) == 0)
    b.add_springs(np.column_stack([np.arange(n - 1), np.arange(1, n)]), 100.0, 0.1)
    return b.finalize()


class _FailAt(Integrator):
    """Symplectic-Euler-like stepper that raises ``exc`` at step ``at`` (1-based)."""

    name = "fail_at"

    def __init__(self, model, at, exc):
        super().__init__(model)
        self.at, self.exc, self.calls = at, exc, 0

    def step(self, state_in, state_out, dt):
        self.calls += 1
        if self.calls == self.at:
            raise self.exc
        qd = state_in.particle_qd + dt * self.acceleration(state_in.particle_q, state_in.particle_qd)
        state_out.particle_qd[...] = qd
        state_out.particle_q[...] = state_in.particle_q + dt * qd
        return StepStats(dt)


def test_blowup_raises_with_finite_frames():
    """Explicit Euler on a 1e8 N/m spring at h = 0.1 s blows up to inf; without the energy check the error names step
    and particle when the state stops being finite, and the frames stay finite."""
    m = _stiff_spring()
    with pytest.raises(SimulationError) as ei:
        simulate(m, make_integrator("explicit_euler", m), 0.1, 500, check_energy=False)
    e = ei.value
    assert e.step is not None and 1 < e.step < 500
    assert f"step {e.step}" in str(e) and "particle 1" in str(e) and "non-finite" in str(e)
    tr = e.trajectory
    assert isinstance(tr, Trajectory)
    assert tr.frame_count == e.step  # frames 0 .. step-1
    assert np.isfinite(tr.q).all() and np.isfinite(tr.qd).all()
    np.testing.assert_allclose(tr.t, np.arange(e.step) * 0.1)
    assert len(tr.stats) == e.step - 1  # the steps whose results were kept
    assert np.all(tr.q[:, 0] == 0.0)  # the fixed particle never moved, even as forces overflowed


def test_energy_bound_stops_a_finite_blowup_early():
    """The same run with the energy check (the default) stops as soon as the state holds more energy than the forces
    can supply, long before anything overflows; the message says so and the kept frames are below the bound."""
    m = _stiff_spring()
    with pytest.raises(SimulationError) as late:
        simulate(m, make_integrator("explicit_euler", m), 0.1, 500, check_energy=False)
    with pytest.raises(SimulationError) as ei:
        simulate(m, make_integrator("explicit_euler", m), 0.1, 500)
    e = ei.value
    assert 1 <= e.step < late.value.step and f"step {e.step}" in str(e)
    assert "more than the forces can supply" in str(e) and "smaller time step" in str(e)
    bound = EnergyBound(m, m.particle_q, m.particle_qd)
    tr = e.trajectory
    assert tr.frame_count == e.step and all(bound.exceeded(q, v) is None for q, v in zip(tr.q, tr.qd))


def test_blowup_keeps_last_finite_state_between_frames():
    """With frame_every > 1 the last finite state before the blow-up is still kept."""
    m = _stiff_spring()
    with pytest.raises(SimulationError) as ei:
        simulate(m, make_integrator("symplectic_euler", m), 0.1, 500, frame_every=7, check_energy=False)
    tr, k = ei.value.trajectory, ei.value.step
    assert tr.t[-1] == pytest.approx((k - 1) * 0.1)
    assert np.isfinite(tr.q).all() and np.isfinite(tr.qd).all()
    assert tr.t.shape[0] == tr.q.shape[0] == tr.qd.shape[0]


def test_blowup_record_false_keeps_initial_and_last_finite():
    """With record=False a blow-up returns the initial and the last finite state."""
    m = _stiff_spring()
    with pytest.raises(SimulationError) as ei:
        simulate(m, make_integrator("midpoint", m), 0.1, 500, record=False, check_energy=False)
    tr, k = ei.value.trajectory, ei.value.step
    np.testing.assert_allclose(tr.t, [0.0, (k - 1) * 0.1])
    assert np.isfinite(tr.q).all()


@pytest.mark.parametrize("exc", [SolverError("linear solver 'x' failed: singular matrix"),
                                 SpringsimError("something springsim-specific")])
def test_springsim_error_mid_run_becomes_simulation_error(exc):
    """A SolverError (or any SpringsimError) at step 4 becomes a SimulationError with 4 frames and the cause."""
    m = _chain()
    integ = _FailAt(m, 4, exc)
    with pytest.raises(SimulationError) as ei:
        simulate(m, integ, 0.01, 10)
    e = ei.value
    assert e.__cause__ is exc
    assert e.step == 4 and "step 4" in str(e) and str(exc) in str(e)
    np.testing.assert_allclose(e.trajectory.t, [0.0, 0.01, 0.02, 0.03])
    assert len(e.trajectory.stats) == 3


def test_newton_raise_mid_run_is_wrapped():
    """implicit_euler with on_nonconvergence='raise' on a stiff cloth stops with SimulationError caused by
    SolverError."""
    b = ModelBuilder()
    b.add_cloth_grid(5, 5, ke=1e7, pin="edge")
    m = b.finalize()
    integ = make_integrator("implicit_euler", m, on_nonconvergence="raise", newton_maxiter=1)
    with pytest.raises(SimulationError) as ei:
        simulate(m, integ, 1.0 / 30, 5)
    assert isinstance(ei.value.__cause__, SolverError)
    assert np.isfinite(ei.value.trajectory.q).all()


def test_interrupt_from_progress_returns_frames_so_far():
    """KeyboardInterrupt from the progress callback gives SimulationInterrupted with the frames so far."""
    m = _chain()

    def progress(k, n):
        if k == 6:
            raise KeyboardInterrupt

    with pytest.raises(SimulationInterrupted) as ei:
        simulate(m, make_integrator("symplectic_euler", m), 0.01, 20, frame_every=4, progress=progress)
    e = ei.value
    assert isinstance(e, KeyboardInterrupt) and not isinstance(e, SimulationError) and e.step == 6
    np.testing.assert_allclose(e.trajectory.t, [0.0, 0.04, 0.06])
    assert "interrupted after step 6 of 20" in str(e)
    ref = simulate(m, make_integrator("symplectic_euler", m), 0.01, 6)
    np.testing.assert_array_equal(e.trajectory.q[-1], ref.q[-1])


def test_interrupt_inside_step_keeps_previous_frames():
    """KeyboardInterrupt raised inside an integrator step keeps every completed step."""
    m = _chain()
    with pytest.raises(SimulationInterrupted) as ei:
        simulate(m, _FailAt(m, 3, KeyboardInterrupt()), 0.01, 10)
    np.testing.assert_allclose(ei.value.trajectory.t, [0.0, 0.01, 0.02])


def test_collective_interrupts_defer_signals_to_the_step_boundary():
    """Over several processes a signal only records itself during a step; the check after the step raises on every
    process when any was signalled, passing the largest signal number the processes agree on to the handler this
    process had for it (so every process records the same signal); a signal after the last check is recorded, never
    raised; the handlers are restored, SIG_DFL ones are left alone, and one process holds nothing."""
    import os
    import signal

    from springsim.run.interrupts import collective_interrupts

    class Fake:
        size, others = 2, 0.0

        def max(self, value):
            return max(value, self.others)

    seen = []

    def handler(signum, frame):
        seen.append(signum)
        raise KeyboardInterrupt

    old_int, old_term = signal.signal(signal.SIGINT, handler), signal.getsignal(signal.SIGTERM)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        system = Fake()
        with collective_interrupts(system) as check:
            assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # not a Python handler: left alone
            os.kill(os.getpid(), signal.SIGINT)  # during a step: recorded, not raised
            assert seen == []
            with pytest.raises(KeyboardInterrupt):
                check()
            assert seen == [signal.SIGINT]
            check()  # nothing pending any more
            system.others = float(signal.SIGINT)  # another process was signalled: this one records it and stops
            with pytest.raises(KeyboardInterrupt):
                check()
            assert seen == [signal.SIGINT, signal.SIGINT]
            system.others = float(signal.SIGTERM)  # a signal this process has no Python handler for: it stops
            with pytest.raises(KeyboardInterrupt):
                check()
            assert seen == [signal.SIGINT] * 2
            system.others = 0.0
            os.kill(os.getpid(), signal.SIGINT)  # after the last check: recorded when the block ends, not raised
        assert seen == [signal.SIGINT] * 3
        assert signal.getsignal(signal.SIGINT) is handler
        system.size = 1
        with collective_interrupts(system) as check:
            assert signal.getsignal(signal.SIGINT) is handler
            check()
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)


def test_driver_argument_validation():
    """Bad dt, steps, frame_every or a non-finite initial state are rejected before stepping, naming the parameter:
    ValueError for bad values, TypeError for wrong types."""
    m = _chain()
    integ = make_integrator("symplectic_euler", m)
    for kw, name in ((dict(dt=0.0, steps=1), "dt"), (dict(dt=np.nan, steps=1), "dt"), (dict(dt=0.1, steps=-1), "steps"),
                     (dict(dt=0.1, steps=1, frame_every=0), "frame_every")):
        with pytest.raises(ValueError, match=f"^{name} "):
            simulate(m, integ, **kw)
    for kw, name in ((dict(dt="0.1", steps=1), "dt"), (dict(dt=True, steps=1), "dt"),
                     (dict(dt=0.1, steps=2.5), "steps"),
                     (dict(dt=0.1, steps=1, frame_every=1.5), "frame_every")):
        with pytest.raises(TypeError, match=f"^{name} "):
            simulate(m, integ, **kw)
    s = m.state()
    s.particle_q[2, 1] = np.inf
    with pytest.raises(ValueError, match="state.particle_q"):
        simulate(m, integ, 0.1, 1, state=s)


def test_zero_steps_returns_initial_frame():
    """steps = 0 returns just the initial state."""
    m = _chain()
    tr = simulate(m, make_integrator("implicit_euler", m), 0.01, 0)
    assert tr.frame_count == 1 and tr.summary()["steps"] == 0
    np.testing.assert_array_equal(tr.q[0], m.particle_q)


def test_save_roundtrip(tmp_path):
    """Trajectory.save writes t, q, qd exactly, at the exact path, with no leftover temporary file."""
    m = _chain()
    tr = simulate(m, make_integrator("implicit_euler", m), 0.01, 5)
    out = tmp_path / "run.npz"
    tr.save(out)
    with np.load(out) as z:
        np.testing.assert_array_equal(z["t"], tr.t)
        np.testing.assert_array_equal(z["q"], tr.q)
        np.testing.assert_array_equal(z["qd"], tr.qd)
    assert sorted(os.listdir(tmp_path)) == ["run.npz"]


def test_saved_metadata_traces_the_run(tmp_path):
    """The .npz carries how it was made (JSON in a 0-d unicode array, no pickling) and load reads it back."""
    import json

    import springsim

    m = _chain()
    tr = simulate(m, make_integrator("implicit_euler", m, solver="direct"), 0.01, 4, frame_every=2)
    out = tmp_path / "run.npz"
    tr.save(out)
    with np.load(out, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
    assert meta == dict(tr.meta, format="springsim-trajectory", format_version=1)
    assert meta["springsim_version"] == springsim.__version__ and meta["model_fingerprint"] == m.fingerprint()
    assert (meta["integrator"], meta["linear_solver"], meta["jacobian"]) == ("implicit_euler", "direct", "mixed")
    assert (meta["dt"], meta["steps"], meta["frame_every"]) == (0.01, 4, 2)
    assert Trajectory.load(out).meta == meta
    ad = springsim.simulate_adaptive(m, "tr_bdf2", 0.05, time_rtol=1e-4, time_atol=1e-5)
    assert (ad.meta["integrator"], ad.meta["t_end"], ad.meta["time_rtol"]) == ("tr_bdf2", 0.05, 1e-4)


def test_load_without_metadata_and_of_a_foreign_format(tmp_path):
    """A bare t/q/qd .npz loads with empty meta; a file of another format or a newer layout is refused by name."""
    import json

    np.savez(tmp_path / "bare.npz", t=np.zeros(1), q=np.zeros((1, 2, 3)), qd=np.zeros((1, 2, 3)))
    assert Trajectory.load(tmp_path / "bare.npz").meta == {}
    for name, meta in (("other.npz", {"format": "other"}), ("newer.npz", {"format_version": 99}),
                       ("list.npz", [1, 2])):
        np.savez(tmp_path / name, t=np.zeros(1), q=np.zeros((1, 2, 3)), qd=np.zeros((1, 2, 3)),
                 meta=np.array(json.dumps(meta)))
        with pytest.raises(SpringsimError, match=name):
            Trajectory.load(tmp_path / name)


def test_model_fingerprint_is_sensitive_and_ignores_metadata():
    """Equal models hash equally whatever their metadata; any change of a parameter changes the hash."""
    a, b = _chain(), _chain()
    assert a.fingerprint() == b.fingerprint() and len(a.fingerprint()) == 64
    object.__setattr__(b, "metadata", {"name": "renamed"})
    assert a.fingerprint() == b.fingerprint()
    assert _chain(seed=6).fingerprint() != a.fingerprint()
    c = ModelBuilder(gravity=-9.8)
    c.add_particles(a.particle_q, a.particle_qd, 0.1, fixed=np.arange(4) == 0)
    c.add_springs(a.spring_indices, 100.0, 0.1)
    assert c.finalize().fingerprint() != a.fingerprint()


@pytest.mark.parametrize("exc", [OSError("disk full"), KeyboardInterrupt()])
def test_atomic_write_failure_leaves_no_partial_file(tmp_path, monkeypatch, exc):
    """A failure half-way through writing leaves no target file and no temporary file."""
    real = np.savez

    def broken(fh, **arrays):
        real(fh, **arrays)  # bytes reach the temporary file ...
        raise exc  # ... then the write fails

    monkeypatch.setattr(np, "savez", broken)
    out = tmp_path / "out.npz"
    with pytest.raises(type(exc)):
        save_npz_atomic(out, q=np.ones((3, 2, 3)))
    assert os.listdir(tmp_path) == []


def test_atomic_write_failure_keeps_previous_file(tmp_path, monkeypatch):
    """A failed overwrite leaves the previous complete file untouched."""
    out = tmp_path / "out.npz"
    save_npz_atomic(out, q=np.arange(6.0))
    before = out.read_bytes()

    def broken(fh, **arrays):
        fh.write(b"PK\x03\x04 partial")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", broken)
    with pytest.raises(OSError):
        save_npz_atomic(out, q=np.zeros(6))
    assert out.read_bytes() == before
    assert os.listdir(tmp_path) == ["out.npz"]


def test_energy_bound_work_is_kinetic_plus_gravity():
    """The bound's W (computed from a scaled copy of the velocities after every step) is T + V_gravity of
    springsim.run.energy; a NaN velocity is never within the bound."""
    from springsim.forces import ForceGravity
    from springsim.run.energy import kinetic_energy, potential_energy

    b = ModelBuilder()
    b.add_cloth_grid(7, 5, pin="top")
    m = b.finalize()
    rng = np.random.default_rng(5)
    q = m.particle_q + rng.normal(scale=0.1, size=m.particle_q.shape)
    qd = rng.normal(size=q.shape)
    bound = EnergyBound(m, m.particle_q, m.particle_qd)
    expected = kinetic_energy(m, qd) + potential_energy(m, q, [ForceGravity.from_model(m)])
    assert bound.work(q, qd) == pytest.approx(expected, rel=1e-12)
    assert bound.work(q, qd) == pytest.approx(expected, rel=1e-12)  # the buffer is reused
    assert bound.work(q, np.zeros_like(qd)) == pytest.approx(expected - kinetic_energy(m, qd), rel=1e-12)
    qd[3, 1] = np.nan
    assert bound.exceeded(q, qd) is not None


def test_energy_growth_of_a_damped_or_conservative_scene_is_reported():
    """Energy growth below the blow-up bound is still an instability: explicit Euler on the damped spring (9.9 J
    to 22.9 J over 10 s at dt = 0.03 s) warns once and fails a step; midpoint on the undamped spring warns without
    failing one (nothing dissipates there); a stable symplectic Euler run (bounded oscillation) does not warn."""
    import warnings
    from pathlib import Path

    from springsim.errors import EnergyGrowthWarning
    from springsim.scene import load_scene

    scenes = Path(__file__).resolve().parents[2] / "scenes"
    damped, undamped = load_scene(scenes / "damped_spring.yaml").model, load_scene(scenes / "spring.yaml").model
    cases = [(damped, "explicit_euler", 0.03, 334, True), (undamped, "midpoint", 0.05, 200, True),
             (undamped, "symplectic_euler", 0.001, 2000, False)]
    for model, name, dt, steps, unstable in cases:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            tr = simulate(model, make_integrator(name, model), dt, steps)
        grew = [w for w in caught if issubclass(w.category, EnergyGrowthWarning)]
        assert len(grew) == int(unstable), (name, [str(w.message) for w in grew])
        failed = tr.summary()["failed_steps"]
        assert failed == int(unstable and model is damped), (name, failed)


def test_an_integrator_shared_by_two_threads_is_refused_not_wrong():
    """A run of an integrator while another thread holds it (its run is mid-step here) raises SpringsimError at once
    in the second thread, for simulate, simulate_adaptive and a direct step; the first run finishes unaffected, equal
    to a run alone."""
    import threading

    from springsim import simulate_adaptive
    from springsim.errors import SpringsimError

    m = _chain()
    integ = make_integrator("tr_bdf2", m, solver="direct")
    alone = simulate(m, make_integrator("tr_bdf2", m, solver="direct"), 0.01, 5)
    inside, release = threading.Event(), threading.Event()
    original = integ.advance

    def slow_advance(q, v, h, stats):
        inside.set()
        release.wait(30)
        return original(q, v, h, stats)

    integ.advance = slow_advance
    result = {}
    worker = threading.Thread(target=lambda: result.setdefault("traj", simulate(m, integ, 0.01, 5)))
    worker.start()
    assert inside.wait(30)
    try:
        for attempt in (lambda: simulate(m, integ, 0.01, 2),
                        lambda: simulate_adaptive(m, integ, 0.05, time_rtol=1e-3, time_atol=1e-3),
                        lambda: integ.step(m.state(), m.state(), 0.01)):
            with pytest.raises(SpringsimError, match="in use by another thread"):
                attempt()
    finally:
        release.set()
        worker.join(60)
    np.testing.assert_array_equal(result["traj"].q, alone.q)
