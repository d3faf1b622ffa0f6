"""Contract tests of every force term's energy-momentum form (``eval_force_discrete``, ``eval_jacobians_discrete``).

The discrete force over a step from ``q0`` to ``q1`` must do exactly minus the change of the term's potential
(Gonzalez 1996), reduce to the ordinary force and Jacobians at ``q0 = q1``, and its Jacobians with respect to the
midpoint must equal central finite differences.
"""

from __future__ import annotations

import numpy as np
import pytest

from helpers import assert_matches_fd, random_scene, rel_err
from springsim.assembly import SystemAssembler
from springsim.forces import FORCE_TERMS, JACOBIAN_MODES, ForceGravitational

FD_RTOL = 1e-6
TERMS = sorted(FORCE_TERMS)


def _scene(name, rng, **kw):
    """A random scene that uses the term ``name``, and the term."""
    for _ in range(20):  # random_scene draws drag and damping for about half the particles and springs
        model = random_scene(rng, **kw)
        term = FORCE_TERMS[name].from_model(model)
        if term is not None:
            return model, term
    raise AssertionError(f"random_scene must exercise the registered term {name!r} (extend tests/helpers.py)")


def _endpoints(model, rng, scale=0.05, step=0.1):
    """A start ``q0`` near the model's configuration, an end ``q1`` a step away (springs turn and stretch), and a
    velocity."""
    q0 = model.particle_q + rng.uniform(-scale, scale, model.particle_q.shape)
    q1 = q0 + rng.uniform(-step, step, q0.shape)
    qd = rng.uniform(-0.5, 0.5, q0.shape)
    return q0, q1, qd


def _discrete(term, q0, q1, qd):
    f = np.zeros_like(q0)
    term.eval_force_discrete(q0, q1, qd, f)
    return f


def _dense(blocks, n):
    return np.zeros((3 * n, 3 * n)) if blocks is None else blocks.toarray(n)


def _work_identity(term, q0, q1):
    """``(F . (q1 - q0), -(V(q1) - V(q0)), scale)`` at zero velocity (no dissipation)."""
    f = _discrete(term, q0, q1, np.zeros_like(q0))
    work = float(np.sum(f * (q1 - q0)))
    dv = term.potential_energy(q1) - term.potential_energy(q0)
    scale = float(np.sum(np.abs(f * (q1 - q0)))) + abs(term.potential_energy(q1)) + abs(term.potential_energy(q0))
    return work, -dv, scale


@pytest.mark.parametrize("name", TERMS)
def test_discrete_force_does_the_potential_work(name):
    """``F . (q1 - q0) = -(V(q1) - V(q0))`` to round-off, for steps that stretch, compress and turn the pairs."""
    rng = np.random.default_rng(741)
    for trial in range(5):
        model, term = _scene(name, rng)
        q0, q1, _ = _endpoints(model, rng, step=0.3)
        work, minus_dv, scale = _work_identity(term, q0, q1)
        assert abs(work - minus_dv) <= 1e-12 * max(scale, 1.0)


EPS = 0.1
#: (|d_0|, |d_1|) of a gravitational pair with softening EPS: outside, inside and across its core
GRAVITATIONAL_CASES = {"far": (0.5, 0.3), "core": (0.05, 0.08), "into_core": (0.3, 0.04), "out_of_core": (0.02, 0.2),
                       "narrow_crossing": (EPS * (1 - 1e-6), EPS * (1 + 1e-6))}


def _gravitational_pair(case):
    """A softened gravitational pair (c = 2.5, eps = EPS) going from ``|d_0|`` to ``|d_1|`` while turning."""
    l0, l1 = GRAVITATIONAL_CASES[case]
    n, t = np.array([0.6, 0.0, 0.8]), np.array([0.0, 1.0, 0.0])
    term = ForceGravitational(np.array([[0, 1]]), np.array([2.5]), EPS)
    return term, np.array([np.zeros(3), l0 * n]), np.array([np.zeros(3), l1 * (0.8 * n + 0.6 * t)])


@pytest.mark.parametrize("case", sorted(GRAVITATIONAL_CASES))
def test_gravitational_discrete_gradient_across_the_core(case):
    """The softened gravitational pair's discrete gradient is exact outside, inside and across its core, also when
    the crossing is narrow (relative to the potential change, which the check computes with rounding 1e-10)."""
    term, q0, q1 = _gravitational_pair(case)
    work, minus_dv, scale = _work_identity(term, q0, q1)
    assert abs(work - minus_dv) <= 1e-8 * abs(minus_dv) + 1e-14 * scale


def _fd_discrete(term, q0, q1, qd, h=1e-7):
    """Central differences of the discrete force with respect to the midpoint (q0 held) and to the velocity, each
    (3N, 3N)."""
    n = q0.shape[0]
    qm = 0.5 * (q0 + q1)
    fq, fqd = np.zeros((3 * n, 3 * n)), np.zeros((3 * n, 3 * n))
    for k in range(3 * n):  # columns of a tiny test scene
        e = np.zeros(3 * n)
        e[k] = h
        e = e.reshape(n, 3)
        fq[:, k] = (_discrete(term, q0, 2 * (qm + e) - q0, qd) - _discrete(term, q0, 2 * (qm - e) - q0, qd)
                    ).reshape(-1) / (2 * h)
        fqd[:, k] = (_discrete(term, q0, q1, qd + e) - _discrete(term, q0, q1, qd - e)).reshape(-1) / (2 * h)
    return fq, fqd


@pytest.mark.parametrize("case", ["far", "core", "into_core", "out_of_core"])
def test_gravitational_discrete_jacobian_across_the_core(case):
    """The exact discrete Jacobian of a gravitational pair equals central differences in and across the core."""
    term, q0, q1 = _gravitational_pair(case)
    J = _dense(term.eval_jacobians_discrete(q0, q1, np.zeros_like(q0), "exact")[0], 2)
    assert rel_err(J, _fd_discrete(term, q0, q1, np.zeros_like(q0))[0]) <= FD_RTOL


@pytest.mark.parametrize("lengths, rest", [((2e-3, 0.5e-3), 1e-2), ((0.5e-3, 2e-3), 0.0), ((2e-3, 3e-3), 1e-2)],
                         ids=["end_below_eps", "start_below_eps_zero_rest", "above_eps"])
def test_spring_discrete_jacobian_near_eps(lengths, rest):
    """A spring with eps = 1e-3 whose length passes below eps: the discrete force's exact Jacobian equals central
    differences (the mean length is used unclamped as long as it is above eps)."""
    from springsim.forces import ForceSpring

    term = ForceSpring(np.array([[0, 1]]), np.array([40.0]), np.array([0.0]), np.array([rest]), eps=1e-3)
    n, t = np.array([0.6, 0.0, 0.8]), np.array([0.0, 1.0, 0.0])
    q0 = np.array([np.zeros(3), lengths[0] * n])
    q1 = np.array([np.zeros(3), lengths[1] * (0.8 * n + 0.6 * t)])
    J = _dense(term.eval_jacobians_discrete(q0, q1, np.zeros_like(q0), "exact")[0], 2)
    assert rel_err(J, _fd_discrete(term, q0, q1, np.zeros_like(q0), h=1e-9)[0]) <= FD_RTOL


@pytest.mark.parametrize("mode", JACOBIAN_MODES)
@pytest.mark.parametrize("name", TERMS)
def test_discrete_form_at_equal_points_is_the_ordinary_one(name, mode):
    """At ``q0 = q1`` the discrete force and its Jacobians (every mode) are the ordinary ones."""
    rng = np.random.default_rng(742)
    model, term = _scene(name, rng)
    q, _, qd = _endpoints(model, rng)
    f = np.zeros_like(q)
    term.eval_force(q, qd, f)
    np.testing.assert_allclose(_discrete(term, q, q, qd), f, rtol=1e-13, atol=1e-13 * np.abs(f).max())
    n = model.particle_count
    for a, b in zip(term.eval_jacobians_discrete(q, q, qd, mode), term.eval_jacobians(q, qd, mode)):
        A, B = _dense(a, n), _dense(b, n)
        np.testing.assert_allclose(A, B, rtol=0, atol=1e-12 * max(np.abs(B).max(), 1.0))


@pytest.mark.parametrize("damping", [True, False], ids=["damped", "undamped"])
@pytest.mark.parametrize("name", TERMS)
def test_discrete_jacobians_match_finite_differences(name, damping):
    """Exact derivatives of the discrete force with respect to the midpoint (``q0`` held) and the velocity equal
    central finite differences (rel. error <= 1e-6)."""
    rng = np.random.default_rng(743)
    for trial in range(3):
        model, term = _scene(name, rng, damping=damping)
        q0, q1, qd = _endpoints(model, rng)
        n = model.particle_count
        jq, jqd = (_dense(b, n) for b in term.eval_jacobians_discrete(q0, q1, qd, "exact"))
        for J, F in zip((jq, jqd), _fd_discrete(term, q0, q1, qd, h=1e-6)):
            assert_matches_fd(J, F, FD_RTOL)


@pytest.mark.parametrize("mode", [m for m in JACOBIAN_MODES if m != "exact"])
@pytest.mark.parametrize("name", TERMS)
def test_discrete_approximate_modes_are_symmetric_and_dissipative(name, mode):
    """The ``symmetric``/``spd`` discrete Jacobians are symmetric; in ``spd`` mode their negatives are PSD."""
    rng = np.random.default_rng(744)
    model, term = _scene(name, rng)
    q0, q1, qd = _endpoints(model, rng, scale=0.3, step=0.3)
    for J in (_dense(b, model.particle_count) for b in term.eval_jacobians_discrete(q0, q1, qd, mode)):
        assert np.abs(J - J.T).max() <= 1e-13 * max(np.abs(J).max(), 1.0)
        if mode == "spd":
            lam = np.linalg.eigvalsh(-0.5 * (J + J.T))
            assert lam.min() >= -1e-10 * max(np.abs(lam).max(), 1.0)


@pytest.mark.parametrize("mode", JACOBIAN_MODES)
@pytest.mark.parametrize("name", TERMS)
def test_assembled_discrete_matrix(name, mode):
    """With ``q_start`` the assembler builds ``M - a K - b D`` from the discrete Jacobians at the midpoint and
    declares it symmetric exactly when the term does."""
    rng = np.random.default_rng(745)
    model, term = _scene(name, rng)
    q0, q1, qd = _endpoints(model, rng)
    qm = 0.5 * (q0 + q1)
    asm = SystemAssembler(model, [term])
    A = asm.assemble(qm, qd, 0.3, 0.7, mode, q_start=q0)
    n = model.particle_count
    jq, jqd = (_dense(b, n) for b in term.eval_jacobians_discrete(q0, q1, qd, mode))
    free = np.repeat(~model.particle_fixed, 3)
    expected = (np.diag(np.repeat(model.particle_mass, 3)) - 0.3 * jq - 0.7 * jqd)[np.ix_(free, free)]
    D = A.toarray()
    np.testing.assert_allclose(D, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    assert A.symmetric == term.jacobian_symmetric_discrete(mode)
    if A.symmetric:
        assert np.abs(D - D.T).max() <= 1e-12 * np.abs(D).max()
