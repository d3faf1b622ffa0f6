"""Force terms against closed forms, momentum conservation and degenerate geometry."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import conservative, fd_jacobians, random_scene, rel_err, two_particle_scene
from springsim import ModelBuilder
from springsim.forces import (JACOBIAN_MODES, ForceDrag, ForceGravitational, ForceGravity, ForceSpring,
                              dense_jacobians, eval_forces, make_force_terms)

INTERNAL = (ForceSpring, ForceGravitational)


@pytest.mark.parametrize("skip_fixed", [True, False])
def test_internal_forces_conserve_linear_momentum(skip_fixed):
    """Spring (with damping) and gravitational forces sum to zero over all particles."""
    rng = np.random.default_rng(811)
    for _ in range(5):
        model = random_scene(rng)
        q = model.particle_q + rng.normal(scale=0.1, size=model.particle_q.shape)
        qd = rng.normal(size=q.shape)
        for cls in INTERNAL:
            term = cls.from_model(model, skip_fixed=skip_fixed)
            f = eval_forces([term], q, qd)
            assert np.abs(f.sum(axis=0)).max() <= 1e-12 * np.abs(f).max()


def test_internal_jacobians_are_translation_invariant():
    """Internal-force Jacobians have zero block-column sums (forces depend only on differences)."""
    rng = np.random.default_rng(812)
    model = random_scene(rng)
    q = model.particle_q + rng.normal(scale=0.1, size=model.particle_q.shape)
    qd = rng.normal(size=q.shape)
    n = model.particle_count
    for cls in INTERNAL:
        jq, jqd = dense_jacobians([cls.from_model(model)], q, qd, "exact")
        for J in (jq, jqd):
            s = J.reshape(3 * n, n, 3).sum(axis=1)
            assert np.abs(s).max() <= 1e-12 * max(np.abs(J).max(), 1.0)


def test_spring_force_closed_form():
    """F_i = -k (l - l0) n - b (n . v) n on i and the opposite on j (seed eqs. 6 and 8)."""
    model = two_particle_scene(ke=40.0, kd=1.5, rest_length=0.6)
    q, qd = model.particle_q, model.particle_qd
    d = q[0] - q[1]
    l = np.linalg.norm(d)
    n = d / l
    v = qd[0] - qd[1]
    expected = -40.0 * (l - 0.6) * n - 1.5 * np.dot(n, v) * n
    f = eval_forces(make_force_terms(model), q, qd)
    np.testing.assert_allclose(f[0], expected, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(f[1], -expected, rtol=1e-14, atol=1e-14)


def test_gravitational_force_closed_form():
    """F_i = -G m_i m_j (q_i - q_j) / |q_i - q_j|^3 on i and the opposite on j (seed 5.5)."""
    model = two_particle_scene(G=2.0)
    q = model.particle_q
    m = model.particle_mass
    d = q[0] - q[1]
    expected = -2.0 * m[0] * m[1] * d / np.linalg.norm(d) ** 3
    f = eval_forces(make_force_terms(model), q, model.particle_qd)
    np.testing.assert_allclose(f[0], expected, rtol=1e-14)
    np.testing.assert_allclose(f[1], -expected, rtol=1e-14)


@pytest.mark.parametrize("up_axis", ["x", "y", "z"])
def test_gravity_closed_form(up_axis):
    """F_i = m_i g e_up on every particle, independent of q and qd, with no Jacobian."""
    rng = np.random.default_rng(813)
    b = ModelBuilder(gravity=-3.7, up_axis=up_axis)
    m = rng.uniform(0.1, 2.0, 5)
    b.add_particles(rng.normal(size=(5, 3)), rng.normal(size=(5, 3)), m)
    model = b.finalize()
    term = ForceGravity.from_model(model)
    f = eval_forces([term], rng.normal(size=(5, 3)), rng.normal(size=(5, 3)))
    expected = np.zeros((5, 3))
    expected[:, "xyz".index(up_axis)] = -3.7 * m
    np.testing.assert_allclose(f, expected, rtol=1e-15)
    assert term.eval_jacobians(model.particle_q, model.particle_qd) == (None, None)


def test_zero_gravity_creates_no_term():
    """A model with gravity 0 instantiates no gravity term (only terms a scene uses exist)."""
    b = ModelBuilder(gravity=0.0)
    b.add_particles(np.zeros((2, 3)) + [[0, 0, 0], [1, 0, 0]], None, 1.0)
    model = b.finalize()
    assert make_force_terms(model) == []


def test_drag_closed_form_and_jacobian():
    """F_i = -beta_i qd_i and dF/dqd = -beta_i I; particles without drag feel none."""
    rng = np.random.default_rng(814)
    beta = np.array([0.0, 0.3, 1.2, 0.0, 0.7])
    b = ModelBuilder(gravity=0.0)
    b.add_particles(rng.normal(size=(5, 3)), rng.normal(size=(5, 3)), 1.0, drag=beta)
    model = b.finalize()
    term = ForceDrag.from_model(model)
    qd = rng.normal(size=(5, 3))
    f = eval_forces([term], model.particle_q, qd)
    np.testing.assert_allclose(f, -beta[:, None] * qd, rtol=1e-15)
    jq, jqd = term.eval_jacobians(model.particle_q, qd)
    assert jq is None
    np.testing.assert_allclose(jqd.toarray(5), -np.diag(np.repeat(beta, 3)), rtol=1e-15)


def test_potential_energy_gradient_is_conservative_force():
    """-grad(potential energy) equals the conservative force (springs without damping, gravitational, gravity)."""
    rng = np.random.default_rng(815)
    model = random_scene(rng, damping=False, select=conservative)
    terms = make_force_terms(model)
    q = model.particle_q + rng.normal(scale=0.05, size=model.particle_q.shape)
    qd = np.zeros_like(q)
    f = eval_forces(terms, q, qd)
    h = 1e-6
    g = np.zeros(q.size)
    for k in range(q.size):  # loop over DOFs of a tiny test scene
        qp, qm = q.copy(), q.copy()
        qp.reshape(-1)[k] += h
        qm.reshape(-1)[k] -= h
        g[k] = sum(t.potential_energy(qp) - t.potential_energy(qm) for t in terms) / (2 * h)
    assert rel_err(-g, f.reshape(-1)) <= 1e-6


# -- degenerate geometry ------------------------------------------------------------------------
def _pair_model(distance, eps, **kw):
    p0 = np.array([0.3, 0.2, 0.1])
    direction = np.array([2.0, -1.0, 2.0]) / 3.0
    return two_particle_scene(q=(p0, p0 + distance * direction), pair_epsilon=eps, **kw)


DEGENERATE = dict(ke=40.0, kd=1.5, G=2.0, rest_length=0.5)


@pytest.mark.parametrize("distance", [0.0, 1e-12, 1e-9, 0.5e-9, 2e-9], ids=lambda d: f"l={d:g}")
@pytest.mark.parametrize("mode", JACOBIAN_MODES)
def test_degenerate_pair_is_finite(distance, mode):
    """A pair at distance 0 or about eps gives finite forces and Jacobians in every mode."""
    model = _pair_model(distance, 1e-9, **DEGENERATE)
    terms = make_force_terms(model)
    q, qd = model.particle_q, model.particle_qd
    assert np.all(np.isfinite(eval_forces(terms, q, qd)))
    for J in dense_jacobians(terms, q, qd, mode):
        assert np.all(np.isfinite(J))
    for t in terms:
        assert np.isfinite(t.potential_energy(q))


@pytest.mark.parametrize("distance_over_eps", [0.0, 0.3, 0.9, 1.1, 3.0])
@pytest.mark.parametrize("rest_length", [0.0, 0.5])
def test_degenerate_pair_finite_differences(distance_over_eps, rest_length):
    """Inside and just outside the eps core, exact Jacobians still match finite differences."""
    eps = 1e-3
    kw = dict(DEGENERATE, rest_length=rest_length)
    model = _pair_model(distance_over_eps * eps, eps, **kw)
    terms = make_force_terms(model)
    q, qd = model.particle_q.copy(), model.particle_qd.copy()
    jq, jqd = dense_jacobians(terms, q, qd, "exact")
    # q step 1e-8 << distance to the eps boundary; the force is linear in qd, so a large
    # qd step avoids round-off against the huge core forces
    fq, fqd = fd_jacobians(terms, q, qd, h=1e-8, h_qd=1e-3)
    assert rel_err(jq, fq) <= 1e-6
    if np.linalg.norm(fqd) == 0:
        assert np.linalg.norm(jqd) == 0
    else:
        assert rel_err(jqd, fqd) <= 1e-6


def test_degenerate_core_is_continuous():
    """The spring and gravitational forces are continuous across the eps boundary."""
    eps = 1e-3
    below = _pair_model(eps * (1 - 1e-9), eps, **DEGENERATE)
    above = _pair_model(eps * (1 + 1e-9), eps, **DEGENERATE)
    fb = eval_forces(make_force_terms(below), below.particle_q, np.zeros((2, 3)))
    fa = eval_forces(make_force_terms(above), above.particle_q, np.zeros((2, 3)))
    assert rel_err(fb, fa) <= 1e-6


def test_spring_curvature_remainder_closed_form():
    """A 1 m spring (k = 1e8 N/m) whose end moves 1 mm across it: its length grows by sqrt(1 + 1e-6) - 1 (about
    5e-7 m) where the linearisation sees no change; the remainder force is -k r along the old direction on the
    first particle and +k r on the second. Moving along the spring leaves no remainder."""
    b = ModelBuilder(gravity=0.0)
    b.add_particle((0.0, 0.0, 0.0))
    b.add_particle((1.0, 0.0, 0.0))
    b.add_spring(0, 1, ke=1e8, kd=0.0, rest_length=1.0)
    model = b.finalize()
    (term,) = make_force_terms(model)
    assert term.curved
    q0 = model.particle_q.copy()
    q1 = q0.copy()
    q1[1, 1] += 1e-3
    out = np.zeros_like(q0)
    term.curvature_remainder(q0, q1, out)
    r = np.sqrt(1.0 + 1e-6) - 1.0
    np.testing.assert_allclose(out, [[1e8 * r, 0, 0], [-1e8 * r, 0, 0]], rtol=1e-9, atol=1e-12)
    along = q0.copy()
    along[1, 0] += 1e-3
    out[...] = 0.0
    term.curvature_remainder(q0, along, out)
    assert np.abs(out).max() <= 1e-16 * 1e8


def test_curvature_remainder_is_second_order():
    """The remainder of every curved term is quadratic in the displacement (halving it quarters the remainder), and
    terms without curved lengths add nothing."""
    model = random_scene(np.random.default_rng(5))
    q0 = model.particle_q
    dq = 1e-3 * np.random.default_rng(1).standard_normal(q0.shape)
    for term in make_force_terms(model):
        big, small = np.zeros_like(q0), np.zeros_like(q0)
        term.curvature_remainder(q0, q0 + dq, big)
        term.curvature_remainder(q0, q0 + 0.5 * dq, small)
        if not term.curved:
            assert not big.any()
            continue
        assert np.abs(big).max() > 0.0
        np.testing.assert_allclose(small, 0.25 * big, rtol=2e-3, atol=1e-12 * np.abs(big).max())


def test_default_softening_is_the_same_on_every_machine():
    """The default softening enters the model and its fingerprint, so its cube root uses IEEE's correctly rounded
    operations only (springsim.forces.gravitational.portable_cbrt; np.cbrt's last bit differs between numpy builds:
    1.24 and 2.4 gave other fingerprints for one scene): pinned bits over 4,000 values spread over the whole
    exponent range, subnormals included, within one unit in the last place of the true root."""
    import hashlib

    from springsim.forces.gravitational import portable_cbrt

    k = np.arange(4000)
    x = np.ldexp(0.5 + (k * 7919 % 4000) / 8000.0, (k * 31) % 2090 - 1070)
    y = portable_cbrt(x)
    assert hashlib.sha256(y.tobytes()).hexdigest() == "6a94c39fa11d5eb6ba733e2a1a9f27924a6b2b4c5946bb0d98e25709e4aabbc0"
    import decimal

    with decimal.localcontext() as ctx:  # the true roots to 40 digits (a test's loop over 400 of the values)
        ctx.prec = 40
        ref = np.array([float(decimal.Decimal(v) ** (decimal.Decimal(1) / 3)) for v in x[::10].tolist()])
    assert np.all(np.abs(y[::10] - ref) <= np.spacing(ref))
    assert np.array_equal(portable_cbrt(np.array([0.0, 1.0, 8.0, 27.0, 0.125])), [0.0, 1.0, 2.0, 3.0, 0.5])
