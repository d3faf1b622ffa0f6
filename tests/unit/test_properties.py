"""Property-based tests (hypothesis) on random small scenes: assembly, momentum, translation and rotation symmetry."""

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from springsim.assembly import SystemAssembler, dense_system_free
from springsim.forces import JACOBIAN_MODES, dense_jacobians, eval_forces, make_force_terms
from springsim.model.builder import ModelBuilder

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])

_coord = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


@st.composite
def scenes(draw, *, fixed=True, gravity=True, drag=True):
    """A random scene of 2-6 particles with springs (some zero rest length, some damped) and gravitational pairs.

    Pairs are at least 1 mm apart so that no pair sits at the eps switch of the degenerate-geometry branch.
    """
    n = draw(st.integers(2, 6))
    q = draw(arrays(np.float64, (n, 3), elements=_coord))
    d = np.linalg.norm(q[:, None] - q[None], axis=-1) + np.eye(n)
    assume(d.min() > 1e-3)
    qd = draw(arrays(np.float64, (n, 3), elements=_coord))
    mass = draw(arrays(np.float64, n, elements=st.floats(0.1, 10.0)))
    is_fixed = draw(arrays(np.bool_, n)) if fixed else np.zeros(n, dtype=bool)
    beta = draw(arrays(np.float64, n, elements=st.sampled_from([0.0, 0.3, 2.0]))) if drag else 0.0
    pair = st.tuples(st.integers(0, n - 1), st.integers(1, n - 1)).map(lambda t: (t[0], (t[0] + t[1]) % n))
    sp = draw(st.lists(pair, min_size=0, max_size=8))
    gp = draw(st.lists(pair, min_size=0, max_size=3))
    b = ModelBuilder(gravity=draw(st.sampled_from([-9.81, 0.0, 3.0])) if gravity else 0.0,
                     up_axis=draw(st.sampled_from(["x", "y", "z"])))
    b.add_particles(q, qd, mass, drag=beta, fixed=is_fixed)
    if sp:
        k = len(sp)
        b.add_springs(np.array(sp), draw(arrays(np.float64, k, elements=st.floats(0.0, 1e3))),
                      draw(arrays(np.float64, k, elements=st.sampled_from([0.0, 0.0, 0.5, 5.0]))),
                      draw(arrays(np.float64, k, elements=st.sampled_from([np.nan, 0.0, 0.3, 1.5]))))
    if gp:
        b.add_gravitationals(np.array(gp), draw(arrays(np.float64, len(gp), elements=st.floats(0.0, 1.0))))
    return b.finalize()


@st.composite
def rotations(draw):
    """A uniformly parametrised rotation matrix (from a random non-zero quaternion)."""
    w, x, y, z = draw(arrays(np.float64, 4, elements=st.floats(-1.0, 1.0)))
    s = w * w + x * x + y * y + z * z
    assume(s > 1e-2)
    w, x, y, z = np.array([w, x, y, z]) / np.sqrt(s)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _close(a, b, rtol=1e-10):
    """``|a - b| <= rtol * max(|a|, |b|, 1)`` elementwise in the max norm."""
    scale = max(np.abs(a).max(initial=0.0), np.abs(b).max(initial=0.0), 1.0)
    np.testing.assert_allclose(a, b, rtol=0, atol=rtol * scale)


@SETTINGS
@given(model=scenes(), mode=st.sampled_from(JACOBIAN_MODES), a=st.floats(0.0, 1.0), b=st.floats(0.0, 1.0))
def test_sparse_assembly_equals_dense(model, mode, a, b):
    """The sparse free-DOF system M - a dF/dq - b dF/dqd equals the naive dense identity-row reference."""
    asm = SystemAssembler(model, make_force_terms(model))
    A = asm.assemble(model.particle_q, model.particle_qd, a, b, mode).toarray()
    _close(A, dense_system_free(model, model.particle_q, model.particle_qd, a, b, mode), 1e-12)


@SETTINGS
@given(model=scenes(fixed=False))
def test_internal_forces_conserve_momentum(model):
    """Without fixed particles the internal terms' forces (``ForceTerm.external`` false) sum to zero and so do the
    Jacobians' block columns."""
    terms = [t for t in make_force_terms(model) if not t.external]
    q, qd = model.particle_q, model.particle_qd
    f = eval_forces(terms, q, qd)
    scale = max(np.abs(f).max(initial=0.0), 1.0)
    np.testing.assert_allclose(f.sum(axis=0), 0.0, atol=1e-12 * scale * model.particle_count)
    n = model.particle_count
    for J in dense_jacobians(terms, q, qd, "exact"):
        col = J.reshape(n, 3, 3 * n).sum(axis=0)  # d(sum_i F_i)/dx = 0
        np.testing.assert_allclose(col, 0.0, atol=1e-12 * max(np.abs(J).max(initial=0.0), 1.0) * n)


@SETTINGS
@given(model=scenes(), shift=arrays(np.float64, 3, elements=st.floats(-10.0, 10.0)),
       mode=st.sampled_from(JACOBIAN_MODES))
def test_translation_invariance(model, shift, mode):
    """Translating the whole scene changes neither forces nor Jacobians."""
    terms = make_force_terms(model)
    q, qd = model.particle_q, model.particle_qd
    _close(eval_forces(terms, q + shift, qd), eval_forces(terms, q, qd), 1e-9)
    for Jt, J in zip(dense_jacobians(terms, q + shift, qd, mode), dense_jacobians(terms, q, qd, mode)):
        _close(Jt, J, 1e-9)


@SETTINGS
@given(model=scenes(gravity=False), R=rotations(), mode=st.sampled_from(JACOBIAN_MODES))
def test_rotation_equivariance(model, R, mode):
    """F(Rq, R qd) = R F(q, qd) and J(Rq, R qd) = (I x R) J (I x R)^T for dF/dq and dF/dqd."""
    terms = make_force_terms(model)
    q, qd = model.particle_q, model.particle_qd
    n = model.particle_count
    qr, qdr = q @ R.T, qd @ R.T
    _close(eval_forces(terms, qr, qdr), eval_forces(terms, q, qd) @ R.T, 1e-10)
    big = np.kron(np.eye(n), R)
    for Jr, J in zip(dense_jacobians(terms, qr, qdr, mode), dense_jacobians(terms, q, qd, mode)):
        _close(Jr, big @ J @ big.T, 1e-10)
