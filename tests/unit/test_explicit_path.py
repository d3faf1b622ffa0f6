"""The fast force path (sparse incidence gathers and scatters, fused buffers) against the naive reference."""

import numpy as np
import pytest
from helpers import random_scene

from springsim import ModelBuilder, make_integrator, simulate
from springsim._runtime import accel as _accel
from springsim.forces import ForceSpring, eval_forces, make_force_terms
from springsim.forces._base import PairIncidence
from springsim.forces.naive import naive_forces
from springsim.scene import benchmark_cloth
from springsim.scene.gallery import BENCHMARK_DT

# the pure path, and the compiled force pass of the `accel` extra (the test extra installs numba, so CI runs both)
needs_numba = pytest.mark.skipif(not _accel.numba_available(), reason="numba (the accel extra) is not installed")
KERNELS = ["numpy", pytest.param("numba", marks=needs_numba)]


def test_incidence_gather_is_exact_and_scatter_sums():
    """D @ x equals x[i] - x[j] bit for bit; D.T @ f equals the np.add.at scatter to round-off."""
    rng = np.random.default_rng(3)
    pairs = rng.integers(0, 50, (400, 2))
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    x = rng.standard_normal((50, 3))
    inc = PairIncidence(pairs)
    np.testing.assert_array_equal(inc.diff(x), x[pairs[:, 0]] - x[pairs[:, 1]])
    f = rng.standard_normal((len(pairs), 3))
    out = np.ones((50, 3))
    inc.scatter(f, out)
    ref = np.ones((50, 3))
    np.add.at(ref, pairs[:, 0], f)
    np.add.at(ref, pairs[:, 1], -f)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-13 * np.abs(f).sum())


@pytest.mark.parametrize("kernels", KERNELS)
@pytest.mark.parametrize("seed", range(12))
def test_force_terms_equal_the_naive_forces(seed, kernels):
    """Every term together gives the naive total force on every free particle, near-degenerate pairs included
    (coincident, closer than pair_epsilon, just farther than it)."""
    rng = np.random.default_rng(seed)
    m = random_scene(rng, n=10, springs=20, gravitational=5)
    q, qd = m.particle_q.copy(), m.particle_qd.copy()
    if seed % 3 == 0:  # a coincident pair and one closer than pair_epsilon
        i, j = m.spring_indices[0]
        q[j] = q[i]
        i, j = m.spring_indices[1]
        q[j] = q[i] + 1e-12
        i, j = m.spring_indices[2]  # just above pair_epsilon: the direction (and the damping) is defined
        q[j] = q[i] + np.array([2e-9, 0.0, 0.0])
    terms = make_force_terms(m, kernels=kernels)
    assert [t.kernels for t in terms if t.name == "spring"] == [kernels]
    f = eval_forces(terms, q, qd)
    ref = naive_forces(m, q, qd)
    free = ~m.particle_fixed
    scale = np.abs(ref[free]).max()
    np.testing.assert_allclose(f[free], ref[free], rtol=0, atol=1e-13 * scale)


@pytest.mark.parametrize("kernels", KERNELS)
def test_symplectic_trajectory_equals_the_naive_stepping(kernels):
    """100 symplectic Euler steps of a damped cloth with a weight: the library matches a loop over naive_forces."""
    b = ModelBuilder()
    grid = b.add_cloth_grid(6, 5, pin="top", damping=0.02, drag=1e-3)
    w = b.add_particle((0.0, 0.0, -0.3), mass=0.1)
    b.add_spring(grid[0], w, stiffness=80.0, damping=0.1)
    m = b.finalize()
    dt, steps = 1e-3, 100
    traj = simulate(m, make_integrator("symplectic_euler", m, force_kernels=kernels), dt, steps, record=False)
    q, qd = m.particle_q.copy(), m.particle_qd.copy()
    inv_m = np.where(m.particle_fixed, 0.0, 1.0 / m.particle_mass)[:, None]
    for _ in range(steps):
        qd = qd + dt * naive_forces(m, q, qd) * inv_m
        q = q + dt * qd
    np.testing.assert_allclose(traj.q[-1], q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(traj.qd[-1], qd, rtol=0, atol=1e-10)


@pytest.mark.parametrize("kernels", KERNELS)
def test_benchmark_cloth_forces_match_at_scale(kernels):
    """On a 32 x 32 benchmark cloth in a perturbed state the fast paths equal the naive one to round-off."""
    m = benchmark_cloth(32, kd=0.1)
    rng = np.random.default_rng(1)
    q = m.particle_q + 0.01 * rng.standard_normal(m.particle_q.shape)
    qd = rng.standard_normal(q.shape)
    f = eval_forces(make_force_terms(m, kernels=kernels), q, qd)
    ref = naive_forces(m, q, qd)
    free = ~m.particle_fixed
    np.testing.assert_allclose(f[free], ref[free], rtol=0, atol=1e-12 * np.abs(ref[free]).max())


@needs_numba
@pytest.mark.parametrize("method, dt, steps, moved", [
    ("symplectic_euler", 2e-4, 300, 1e-3), ("explicit_euler", 2e-5, 200, 1e-6), ("midpoint", 2e-5, 200, 1e-6)])
def test_compiled_cloth_trajectory_equals_the_pure_one(method, dt, steps, moved):
    """A damped 24 x 24 cloth (above the size where "auto" compiles) with each explicit integrator: the compiled
    force pass (and symplectic Euler's compiled update) gives the pure path's trajectory to round-off."""
    m = benchmark_cloth(24, kd=0.05)
    auto = make_integrator(method, m)
    assert [t.kernels for t in auto.terms if t.name == "spring"] == ["numba"]
    runs = [simulate(m, make_integrator(method, m, force_kernels=k), dt, steps, record=False)
            for k in ("numpy", "numba")]
    assert np.abs(runs[0].q[-1] - m.particle_q).max() > moved  # it moved
    np.testing.assert_allclose(runs[1].q[-1], runs[0].q[-1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(runs[1].qd[-1], runs[0].qd[-1], rtol=0, atol=1e-9)


@needs_numba
@pytest.mark.parametrize("method", ["implicit_euler", "tr_bdf2"])
def test_compiled_forces_keep_the_implicit_trajectories(method):
    """20 frames of a damped 24 x 24 cloth with Newton (direct solver, tolerance 1e-10) at h = 1/60 s: compiled
    and numpy forces give the same frames to 1e-10 m (the forces agree to round-off; a Newton iteration more
    or less moves a state by about the tolerance times h) and the same Newton iteration counts within one."""
    m = benchmark_cloth(24, kd=0.05)
    runs = {}
    for k in ("numpy", "numba"):
        integ = make_integrator(method, m, solver="direct", force_rtol=1e-10, newton_maxiter=50, force_kernels=k)
        assert [t.kernels for t in integ.terms if t.name == "spring"] == [k]
        runs[k] = simulate(m, integ, BENCHMARK_DT, 20)
        assert all(st.newton_converged for st in runs[k].stats)
    assert np.abs(runs["numpy"].q[-1] - m.particle_q).max() > 0.05  # it fell
    np.testing.assert_allclose(runs["numba"].q, runs["numpy"].q, rtol=0, atol=1e-10)
    its = [[st.newton_iterations for st in runs[k].stats] for k in ("numpy", "numba")]
    assert np.max(np.abs(np.subtract(*its))) <= 1


@needs_numba
def test_compiled_symplectic_update_equals_the_numpy_update():
    """With the compiled force pass symplectic Euler also updates in one compiled pass. Given the same forces
    (masses not a power of two) it gives the numpy update's state (the same IEEE operations in the same
    order; compared to a few ulps), and a fixed particle whose force overflowed keeps its velocity (no
    inf * 0 = NaN)."""
    m = benchmark_cloth(24, kd=0.05, total_mass=0.7)
    compiled = make_integrator("symplectic_euler", m, force_kernels="numba")
    plain = make_integrator("symplectic_euler", m, force_kernels="numba")
    plain._update = None  # the numpy update after the same compiled forces
    assert compiled._update is not None
    assert make_integrator("symplectic_euler", m, force_kernels="numpy")._update is None
    rng = np.random.default_rng(5)
    s = m.state()
    s.particle_q += 0.01 * rng.standard_normal(s.particle_q.shape)
    s.particle_qd += rng.standard_normal(s.particle_qd.shape)
    h = 1e-4
    outs = [m.state(), m.state()]
    for integ, out in zip((plain, compiled), outs):
        integ.step(s, out, h)
    a = eval_forces(compiled.terms, s.particle_q, s.particle_qd) * compiled._inv_mass
    ulp = np.finfo(float).eps
    dv = np.abs(s.particle_qd) + np.abs(a * h)
    assert np.all(np.abs(outs[1].particle_qd - outs[0].particle_qd) <= 4 * ulp * dv)
    dq = np.abs(s.particle_q) + h * (dv + np.abs(outs[0].particle_qd))
    assert np.all(np.abs(outs[1].particle_q - outs[0].particle_q) <= 4 * ulp * dq)
    pinned = int(np.flatnonzero(m.particle_fixed)[0])
    s.particle_q[pinned] = 1e306  # its springs' forces overflow to inf
    with np.errstate(over="ignore", invalid="ignore"):
        for integ, out in zip((plain, compiled), outs):
            integ.step(s, out, h)
            np.testing.assert_array_equal(out.particle_qd[pinned], s.particle_qd[pinned])
            assert np.isfinite(out.particle_q[pinned]).all()


def test_eval_forces_starts_from_the_constant_force():
    """The sum starts from gravity's constant force (one pass less) and equals the sum from zero."""
    m = benchmark_cloth(8, kd=0.1)
    terms = make_force_terms(m)
    assert terms[0].constant_force() is not None and all(t.constant_force() is None for t in terms[1:])
    rng = np.random.default_rng(2)
    q = m.particle_q + 0.01 * rng.standard_normal(m.particle_q.shape)
    qd = rng.standard_normal(q.shape)
    ref = np.zeros_like(q)
    for t in terms:
        t.eval_force(q, qd, ref)
    out = np.full_like(q, np.nan)
    assert eval_forces(terms, q, qd, out=out) is out
    np.testing.assert_array_equal(out, ref)
    rest = np.zeros_like(q)
    for t in terms[1:]:
        t.eval_force(q, qd, rest)
    np.testing.assert_array_equal(eval_forces(iter(terms[1:]), q, qd), rest)  # any iterable of terms
    np.testing.assert_array_equal(eval_forces([], q, qd), np.zeros_like(q))
    assert not np.signbit(terms[0].constant_force()[terms[0].constant_force() == 0]).any()  # no -0.0


def test_force_kernels_option(monkeypatch):
    """"auto" compiles only from ForceSpring.auto_min_pairs springs on and only with numba; bad values and
    "numba" without numba are clear errors; the core works without numba."""
    small, large = benchmark_cloth(4), benchmark_cloth(24)
    assert large.spring_count >= ForceSpring.auto_min_pairs > small.spring_count
    spring = [t for t in make_force_terms(small) if t.name == "spring"][0]
    assert spring.kernels == "numpy"
    with pytest.raises(ValueError, match="kernels must be one of 'auto', 'numba', 'numpy', got 'fortran'"):
        make_force_terms(small, kernels="fortran")
    if _accel.numba_available():  # installed but not importable (e.g. built for another numpy): "auto" falls back
        import sys

        import springsim.forces

        monkeypatch.delattr(springsim.forces, "_numba_kernels", raising=False)
        monkeypatch.setitem(sys.modules, "springsim.forces._numba_kernels", None)
        assert [t.kernels for t in make_force_terms(large) if t.name == "spring"] == ["numpy"]
        with pytest.raises(ValueError, match="kernels='numba': numba does not import"):
            make_force_terms(large, kernels="numba")
    monkeypatch.setattr(_accel, "numba_available", lambda: False)
    assert [t.kernels for t in make_force_terms(large) if t.name == "spring"] == ["numpy"]
    with pytest.raises(ValueError, match=r"needs numba.*springsim\[accel\]"):
        make_integrator("symplectic_euler", large, force_kernels="numba")


@pytest.mark.slow
def test_explicit_speed_benchmark_quick(tmp_path, capsys):
    """The benchmark runs at its tiny size and reports speed with the state difference between the paths."""
    import csv

    from benchmarks import explicit_speed

    assert explicit_speed.main(["--quick", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "explicit_speed.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == explicit_speed.COLUMNS and all(float(r["max_state_diff_m"]) < 1e-12 for r in rows)
    assert [r["kernels"] for r in rows] == (["numpy", "numba"] if _accel.numba_available() else ["numpy"])
    assert "| n | springs |" in capsys.readouterr().out
