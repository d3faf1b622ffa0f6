"""Adaptive stepping: tolerance scaling, exact frame times, statistics, history reuse, input errors."""

import numpy as np
import pytest

from springsim import ModelBuilder, SceneError, make_integrator, simulate
from springsim.analysis.reference import reference_trajectory
from springsim.run.adaptive import hermite_frame, simulate_adaptive


def _oscillator():
    """A particle on an undamped 100 N/m spring (period ~0.63 s), no gravity."""
    b = ModelBuilder(gravity=0.0)
    b.add_particle((0.0, 0.0, 0.0), fixed=True)
    b.add_particle((1.3, 0.1, 0.0), vel=(0.0, 0.5, 0.0), mass=1.0)
    b.add_spring(0, 1, ke=100.0, kd=0.0, rest_length=1.0)
    return b.finalize()


@pytest.fixture(scope="module")
def oscillator_case():
    """The oscillator and its Radau reference at t = 1 s."""
    model = _oscillator()
    return model, reference_trajectory(model, [0.0, 1.0]).q[-1]


@pytest.mark.parametrize("name", ["bdf2", "tr_bdf2", "energy_momentum"])
def test_error_scales_with_tolerance(oscillator_case, name):
    """Tighter time tolerance gives a smaller final error and more steps."""
    model, q_ref = oscillator_case
    errs, steps = [], []
    for tol in (1e-3, 1e-5, 1e-7):
        tr = simulate_adaptive(model, name, 1.0, time_rtol=tol, time_atol=tol, newton_tol=1e-12,
                               newton_maxiter=20)
        errs.append(np.linalg.norm(tr.q[-1] - q_ref))
        steps.append(tr.adaptive_stats["accepted"])
    assert errs[0] > 10 * errs[1] > 100 * errs[2]
    assert steps[0] < steps[1] < steps[2]


@pytest.mark.parametrize("name", ["bdf2", "tr_bdf2", "energy_momentum"])
def test_frames_land_at_requested_times(name):
    """Output frames are exactly at 0 and the requested times, including one at t_end."""
    model = _oscillator()
    t_frames = np.array([0.013, 0.1, 0.25, 0.2501, 0.7])
    tr = simulate_adaptive(model, name, 0.7, t_frames=t_frames, time_rtol=1e-4, time_atol=1e-5)
    assert np.array_equal(tr.t, np.concatenate([[0.0], t_frames]))
    assert tr.q.shape == (6, 2, 3) and tr.qd.shape == (6, 2, 3)
    tr2 = simulate_adaptive(model, name, 1.0, frame_dt=1 / 60, time_rtol=1e-4, time_atol=1e-5)
    assert tr2.t.size == 61 and tr2.t[-1] == 1.0
    assert np.array_equal(tr2.t[1:-1], (1 / 60) * np.arange(1, 60))
    # the fixed particle never moves in interpolated frames
    assert np.array_equal(tr2.q[:, 0], np.zeros((61, 3)))


def test_interpolated_frames_are_accurate(oscillator_case):
    """Hermite frames between step ends are as accurate as the step ends (the last frame is one)."""
    model = _oscillator()
    t_frames = np.linspace(0.05, 1.0, 20)
    ref = reference_trajectory(model, np.concatenate([[0.0], t_frames]))
    tr = simulate_adaptive(model, "tr_bdf2", 1.0, t_frames=t_frames, time_rtol=1e-5, time_atol=1e-5,
                           newton_tol=1e-12, newton_maxiter=20)
    eq = np.linalg.norm(tr.q - ref.q, axis=(1, 2))
    ev = np.linalg.norm(tr.qd - ref.qd, axis=(1, 2))
    assert np.max(eq) <= 2.0 * eq[-1] and eq[-1] < 1e-3
    assert np.max(ev) <= 2.0 * ev[-1] and ev[-1] < 1e-2


def test_hermite_frame_is_exact_for_cubics():
    """Cubic Hermite interpolation reproduces a cubic and its derivative."""
    rng = np.random.default_rng(9157)
    c = rng.normal(size=(4, 3, 3))

    def y(t):
        return c[0] + c[1] * t + c[2] * t**2 + c[3] * t**3

    def dy(t):
        return c[1] + 2 * c[2] * t + 3 * c[3] * t**2

    q, v = hermite_frame(0.2, y(0.2), dy(0.2), 0.7, y(0.7), dy(0.7), 0.45)
    assert np.allclose(q, y(0.45), rtol=1e-12, atol=1e-12)
    assert np.allclose(v, dy(0.45), rtol=1e-12, atol=1e-12)


def test_statistics_and_step_bounds():
    """Statistics count steps and iterations; steps respect h_max; rejections are counted."""
    model = _oscillator()
    tr = simulate_adaptive(model, "bdf2", 1.0, time_rtol=1e-6, time_atol=1e-6, h0=0.2, h_max=0.05)
    s = tr.adaptive_stats
    assert s["accepted"] == len(tr.stats) > 0
    assert s["rejected"] >= 1  # h0 = 0.2 is clipped to 0.05, still far too large for 1e-6
    assert 0 < s["h_min"] <= s["h_mean"] <= s["h_max"] <= 0.05
    assert s["newton_iterations"] >= s["accepted"]


def test_bdf2_history_continues_and_retries():
    """BDF2 uses implicit Euler only for its first step; a retry from the same input reuses the history."""
    model = _oscillator()
    integ = make_integrator("bdf2", model)
    tr = simulate(model, integ, 0.01, 5)
    assert [bool(s.extra.get("bdf2_start")) for s in tr.stats] == [True, False, False, False, False]
    s0, s1, s2 = model.state(), model.state(), model.state()
    integ.reset()
    integ.step(s0, s1, 0.01)
    integ.step(s1, s2, 0.02)
    q_first = s2.particle_q.copy()
    st = integ.step(s1, s2, 0.02)  # retry from the same input
    assert not st.extra.get("bdf2_start")
    assert np.array_equal(s2.particle_q, q_first)


def test_invalid_input():
    """Bad tolerances, frame times and integrators raise SceneError naming the field."""
    model = _oscillator()
    with pytest.raises(SceneError, match="time_rtol"):
        simulate_adaptive(model, "bdf2", 1.0, time_rtol=0.0, time_atol=0.0)
    with pytest.raises(SceneError, match="t_frames"):
        simulate_adaptive(model, "bdf2", 1.0, t_frames=[0.5, 0.2])
    with pytest.raises(SceneError, match="^integrator: adaptive stepping needs"):
        simulate_adaptive(model, "implicit_euler", 1.0)


def test_estimating_flag_is_restored_when_the_run_fails():
    """The adaptive driver turns the integrator's ``estimating`` on for the run and back off even when it raises."""
    from springsim.errors import SimulationError

    model = _oscillator()
    integ = make_integrator("energy_momentum", model)
    assert not integ.estimating
    with pytest.raises(SimulationError):
        simulate_adaptive(model, integ, 1.0, time_rtol=1e-3, time_atol=1e-3, max_steps=3)
    assert not integ.estimating


def test_a_step_without_an_estimate_is_a_failed_attempt(monkeypatch):
    """A step that reports ok but leaves no error estimate is never accepted: it is retried smaller."""
    model = _oscillator()
    integ = make_integrator("tr_bdf2", model)
    real = type(integ).step
    calls = []

    def step(self, s_in, s_out, dt):
        st = real(self, s_in, s_out, dt)
        calls.append(dt)
        if len(calls) == 1:
            self.error_estimate = None
        return st

    monkeypatch.setattr(type(integ), "step", step)
    tr = simulate_adaptive(model, integ, 0.1, time_rtol=1e-3, time_atol=1e-3, h0=0.02)
    assert tr.adaptive_stats["failed_attempts"] == 1 and calls[1] == pytest.approx(calls[0] / 4)


def test_unreachable_tolerance_stops_promptly_with_an_error(tmp_path):
    """``springsim run scenes/spring.yaml --integrator tr_bdf2 --time-rtol 1e-300 --duration 1e-4 --dt 1e-4`` ends
    at once with exit 1 and one 'cannot meet the tolerance' line (it used to stretch the last step to the end, get
    it rejected, shrink it to h_min and stretch it again, without end)."""
    import subprocess
    import sys
    import time
    from pathlib import Path

    scene = Path(__file__).resolve().parents[2] / "scenes" / "spring.yaml"
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "springsim", "run", str(scene), "--integrator", "tr_bdf2",
                        "--time-rtol", "1e-300", "--duration", "0.0001", "--dt", "0.0001"],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert time.monotonic() - t0 < 60
    assert r.returncode == 1 and "cannot meet the tolerance" in r.stderr and "Traceback" not in r.stderr


def test_steps_at_h_min_that_miss_the_tolerance_are_not_accepted():
    """A step forced to h_min whose error is above the tolerance is never accepted as if it had met it: the run
    stops with SimulationError naming h_min, the frames before it kept (h_min = 2^-6 s, time_rtol = 1e-13)."""
    from springsim.errors import SimulationError

    model = _oscillator()
    with pytest.raises(SimulationError, match="cannot meet the tolerance") as e:
        simulate_adaptive(model, "tr_bdf2", 1.0, h_min=2.0 ** -6, h0=2.0 ** -6, time_rtol=1e-13, time_atol=1e-13)
    assert "h_min" in str(e.value) and e.value.trajectory.frame_count >= 1


def test_step_size_controller_accepts_and_chooses_the_next_step():
    """The elementary controller: accept at err <= 1; h min(grow, max(shrink, safety err^(-1/(p+1)))) after an
    accepted step, never growing right after a rejection; at least 10 % smaller after a rejection; h/4 after a
    failed attempt; always within [h_min, h_max]."""
    from springsim.run.adaptive import StepSizeController

    c = StepSizeController(2, h_min=1e-4, h_max=0.1)
    assert (c.safety, c.grow, c.shrink) == (0.9, 4.0, 0.2)
    assert c.accepts(1.0) and c.accepts(0.0) and not c.accepts(1.0 + 1e-12)
    assert c.accepted(0.01, 0.5) == pytest.approx(0.01 * 0.9 * 0.5 ** (-1 / 3))
    assert c.accepted(0.01, 1e-9) == pytest.approx(0.04)  # bounded by grow
    assert c.accepted(0.01, 0.0) == pytest.approx(0.04)  # no error: grow
    assert c.accepted(0.01, 1.0) == pytest.approx(0.009)  # safety
    assert c.accepted(0.05, 1e-9) == 0.1  # h_max
    assert c.rejected(0.01, 2.0) == pytest.approx(0.01 * 0.9 * 2.0 ** (-1 / 3))
    assert c.just_rejected
    assert c.accepted(0.01, 1e-9) == pytest.approx(0.01)  # no growth right after a rejection ...
    assert not c.just_rejected and c.accepted(0.01, 1e-9) == pytest.approx(0.04)  # ... then again
    assert c.rejected(0.01, 1.0 + 1e-9) == pytest.approx(0.009)  # at least 10 % smaller
    assert c.rejected(0.01, 1e6) == pytest.approx(0.002)  # bounded by shrink
    assert c.rejected(2e-4, 1e6) == 1e-4  # h_min
    assert c.failed(0.01) == pytest.approx(0.0025) and c.just_rejected
    assert c.failed(2e-4) == 1e-4
    assert c.at_h_min(1e-4) and not c.at_h_min(1.01e-4)
    assert StepSizeController(4, h_min=1e-4, h_max=0.1).accepted(0.01, 0.5) == pytest.approx(
        0.01 * 0.9 * 0.5 ** (-1 / 5))  # the exponent follows the order


def test_step_size_controller_first_step_and_end_of_run():
    """The first step is h0 (default min(1e-3, h_max)) clipped to [h_min, h_max]; a step lands on the end of the run,
    and where less than h_min would remain after it, the rest is split into two equal steps."""
    from springsim.run.adaptive import StepSizeController

    c = StepSizeController(2, h_min=1e-4, h_max=0.1, safety=0.8, grow=2.0, shrink=0.5)
    assert c.first_step() == 1e-3 and c.first_step(1.0) == 0.1 and c.first_step(1e-9) == 1e-4
    assert StepSizeController(2, h_min=1e-6, h_max=1e-4).first_step() == 1e-4
    assert c.fit(0.01, 1.0) == 0.01
    assert c.fit(0.01, 0.01 * (1 + 1e-13)) == 0.01 * (1 + 1e-13)  # lands on the end
    assert c.fit(0.01, 0.005) == 0.005
    assert c.fit(0.01, 0.01 + 5e-5) == pytest.approx(0.5 * (0.01 + 5e-5))  # two steps, not one stretched
    assert c.accepted(0.01, 1e-9) == pytest.approx(0.02) and c.rejected(0.01, 1e6) == pytest.approx(0.005)
    for lo, hi in ((0.0, 1.0), (0.2, 0.1), (-1.0, 1.0)):
        with pytest.raises(SceneError, match="h_min"):
            StepSizeController(2, h_min=lo, h_max=hi)


def test_stage_tolerance_is_capped_by_the_time_tolerance():
    """During an adaptive run the minimise stages stop at ``force_rtol`` capped at ``NEWTON_SHARE time_rtol`` (the
    Newton error below the error test): every accepted step's force imbalance ratio is within 0.1 time_rtol (or
    its round-off allowance), and the cap is lifted when the run ends."""
    from springsim.run.adaptive import NEWTON_SHARE
    from springsim.scene.gallery import benchmark_cloth

    model = benchmark_cloth(5)
    integ = make_integrator("tr_bdf2", model)
    assert integ.options.force_rtol == 1e-3 and integ.stage.force_rtol_cap is None
    tr = simulate_adaptive(model, integ, 0.1, time_rtol=1e-5, time_atol=1e-5)
    assert tr.stats and all(s.newton_converged for s in tr.stats)
    ratios = [s.residual_ratio for s in tr.stats if "roundoff_stops" not in s.extra]
    assert ratios and max(ratios) <= NEWTON_SHARE * 1e-5 * 1.001
    assert integ.stage.force_rtol_cap is None
    fixed = simulate(model, integ, 0.01, 3)  # a fixed-step run after it: the option's own tolerance again
    assert max(s.residual_ratio for s in fixed.stats) <= 1e-3
