"""Shared test helpers: small random scenes and finite-difference Jacobians.

Import from tests as ``from helpers import random_scene`` (``tests/`` is on
``sys.path`` through ``tests/conftest.py``).
"""

from __future__ import annotations

import functools

import numpy as np

from springsim import ModelBuilder
from springsim.analysis.reference import reference_trajectory
from springsim.forces import eval_forces

__all__ = ["PENDULUM_YAML", "TWO_CLOTHS_YAML", "mixed_scene_yaml", "assert_same_part", "random_scene", "internal", "conservative", "two_particle_scene", "damped_chain", "fd_jacobians", "rel_err", "observed_errors",
           "run_cli", "one_line_error"]


#: A two-particle spring scene (one fixed, one hanging) in the assignment's YAML format: 5 implicit Euler steps.
PENDULUM_YAML = """
solver: {type: implicit_euler, timestep: 0.01, steps: 5}
particles:
  - {pos: [0, 0, 1], mass: 1, fixed: true}
  - {pos: [0, 0, 0], mass: 1}
springs:
  - {particle_ids: [0, 1], stiffness: 100}
"""


#: Two generator blocks and a ``pin:``, no item lists: neither one generator block alone (generated per rank) nor a
#: file with lists, but read in parts all the same.
TWO_CLOTHS_YAML = """
solver: {type: implicit_euler, timestep: 0.01, steps: 3}
cloth:
  - {nx: 5, ny: 4, size: [1, 1], pin: top}
  - {nx: 4, ny: 6, origin: [2, 0, 0], spacing: 0.25, damping: 0.3, pin: none}
pin: [23, {box: [[2.4, 0.9, -1], [3, 1.1, 1]]}]
"""


def mixed_scene_yaml(n: int = 40, seed: int = 3, cloths: bool = False) -> str:
    """A scene file that uses the format's freedoms: its pair lists before its particles, an alias into a top-level
    ``x-`` key, ``ke`` for ``stiffness``, rest lengths given and computed, gravitational pairs with and without a
    softening, drag on some particles, fixed particles given in the items and by a ``pin:`` of indices and a box,
    a spring between two fixed particles; ``up_axis: y``. With ``cloths``, also two generator blocks (a 5 x 4 cloth
    pinned at its top and a 6 x 3 one pinned by a box, with drag and damping), two springs joining explicit particles
    to cloth particles, and a ``pin:`` index among the cloths' particles. Its arrays come from a seeded generator,
    printed to 4 digits (the same file on every machine)."""
    rng = np.random.default_rng(seed)
    lines = ["name: mixed", "x-rest: &v0 [0.0, 0.0, 0.0]", "springs:"]
    for k in range(int(1.75 * n)):
        i, j = rng.choice(n, 2, replace=False)
        rest = "" if k % 3 else f", rest_length: {0.05 + 0.01 * k:.3f}"
        key = "ke" if k % 5 == 0 else "stiffness"
        lines.append(f"  - {{particle_ids: [{i}, {j}], {key}: {100 + k}.0, damping: {0.1 * (k % 2):.1f}{rest}}}")
    lines.append("  - {particle_ids: [0, 1], stiffness: 5.0}")
    lines.append("solver: {type: implicit_euler, timestep: 0.01, steps: 5, gravity: -3.0, up_axis: y}")
    lines.append("particles:")
    for i in range(n):
        fixed = ", fixed: true" if i in (0, 1) else ""
        drag = f", drag: {0.01 * (i % 3):.2f}" if i % 4 == 0 else ""
        vel = "vel: *v0" if i % 2 else f"vel: [{rng.normal():.3f}, 0.1, 0.0]"
        pos = ", ".join(f"{x:.4f}" for x in rng.normal(size=3))
        lines.append(f"  - {{pos: [{pos}], {vel}, mass: {0.5 + 0.1 * (i % 5):.2f}{drag}{fixed}}}")
    lines.append("gravitational:")
    for k in range(max(n // 3, 2)):
        i, j = rng.choice(n, 2, replace=False)
        soft = "" if k % 2 else ", softening: 0.05"
        lines.append(f"  - {{particle_ids: [{i}, {j}], G: 0.5{soft}}}")
    if not cloths:
        lines.append(f"pin: [7, {{box: [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]}}, {n - 10}]")
        return "\n".join(lines) + "\n"
    lines.append(f"pin: [7, {{box: [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]}}, {n - 10}, {n + 22}]")
    lines.append("cloth:")
    lines.append("  - {nx: 5, ny: 4, origin: [3, 0, 0], size: [1, 1], pin: top, ke: 300}")
    lines.append("  - {nx: 6, ny: 3, origin: [0, 3, 0], plane: xz, spacing: 0.2, drag: 0.01, damping: 0.2, "
                 "bending: false, pin: [{box: [[-1, 2, -1], [0.3, 4, 1]]}]}")
    springs = lines.index("springs:")
    lines.insert(springs + 1, f"  - {{particle_ids: [2, {n + 3}], stiffness: 50.0}}")
    lines.insert(springs + 1, f"  - {{particle_ids: [{n + 25}, 4], stiffness: 60.0, rest_length: 0.5}}")
    return "\n".join(lines) + "\n"


def assert_same_part(got, ref):
    """Two ScenePart s (springsim.distributed) are the same to the last bit: the local part (particles, numbering,
    the pair and particle models), the fixed particles and their model, the whole scene's numbers; and ``got`` has
    ``ref``'s model's fingerprint when ``ref`` has one."""
    for k in ("local_particles", "local_to_free", "offsets"):
        assert np.array_equal(getattr(got.part, k), getattr(ref.part, k)), k
    assert (got.part.n_own, got.part.n_ghost) == (ref.part.n_own, ref.part.n_ghost)
    for a, b in ((got.part.pair_model, ref.part.pair_model), (got.part.particle_model, ref.part.particle_model),
                 (got.fixed_model, ref.fixed_model)):
        for k in ("particle_q", "particle_qd", "particle_mass", "particle_radius", "particle_fixed"):
            assert np.array_equal(getattr(a, k), getattr(b, k), equal_nan=True), k
        assert list(a.terms) == list(b.terms)
        for t in a.terms:
            assert list(a.terms[t]) == list(b.terms[t])
            for k in a.terms[t]:
                assert np.array_equal(a.terms[t][k], b.terms[t][k], equal_nan=True), (t, k)
        assert (a.gravity, a.up_axis, a.pair_epsilon, a.metadata) == (b.gravity, b.up_axis, b.pair_epsilon,
                                                                      b.metadata)
    assert np.array_equal(got.fixed_ids, ref.fixed_ids)
    for k in ("particle_count", "free_count", "gravity", "up_axis", "pair_epsilon", "damped", "metadata",
              "cloth_grids", "pair_counts"):
        assert getattr(got, k) == getattr(ref, k), k


def _spring_data(rng, b, pos, is_fixed, o):
    """The built-in springs of :func:`random_scene` (``o``: its options)."""
    n, springs, damping = pos.shape[0], o["springs"], o["damping"]
    if springs:
        ij = o["pairs"](springs)
        kd = np.where(rng.random(springs) < 0.5, rng.uniform(0.1, 2.0, springs), 0.0) if damping else 0.0
        d = np.linalg.norm(pos[ij[:, 0]] - pos[ij[:, 1]], axis=1)
        l0 = np.where(rng.random(springs) < 0.5, np.nan, d * rng.uniform(0.5, 1.5, springs))
        b.add_springs(ij, rng.uniform(*o["ke"], springs), kd, l0)
        if o["duplicate"]:
            b.add_springs(ij[:1], rng.uniform(*o["ke"]), kd if np.ndim(kd) == 0 else kd[:1])


def _gravitational_data(rng, b, pos, is_fixed, o):
    if o["gravitational"]:
        b.add_gravitationals(o["pairs"](o["gravitational"]), rng.uniform(*o["G"], o["gravitational"]))


def _fixed_pairs(b, f, o):
    """The built-in pairs between two fixed particles ``f``."""
    if "spring" in o["terms"]:
        b.add_spring(int(f[0]), int(f[1]), ke=50.0, kd=0.5 if o["damping"] else 0.0)
    if "gravitational" in o["terms"]:
        b.add_gravitational(int(f[0]), int(f[1]), G=1.0)


def _drag_data(rng, n, o):
    return {"drag": np.where(rng.random(n) < 0.5, rng.uniform(0.1, 1.0, n), 0.0)} if o["drag"] else {}


#: Generators of the built-in terms' random data (their tuned distributions): per-particle arrays, drawn with the
#: particles, and pairs; :func:`random_scene` draws the data of every other registered term from its declarations
#: (:func:`_declared_data`).
RANDOM_PARTICLES = {"drag": _drag_data}
RANDOM_PAIRS = {"spring": _spring_data, "gravitational": _gravitational_data}


def _declared_values(rng, spec, count):
    """``count`` random values of ``spec`` in its sample range (NaN, the computed value, for about half where
    the spec is computed)."""
    lo, hi = spec.sample_range()
    v = rng.uniform(lo, hi, (count,) + tuple(spec.shape))
    if spec.computed:
        v[rng.random(count) < 0.5] = np.nan
    return v


def _declared_data(rng, b, name, cls, n, is_fixed, o, particle_arrays):
    """Random data of a term from its declared :class:`~springsim.forces.ArraySpec` s: 3 pairs (and one between two
    fixed particles), values for about half the particles, per-model values."""
    specs = cls.data
    if any(s.per == "pair" for s in specs):
        k = 3
        ij = o["pairs"](k)
        if o["fixed_pairs"] and o["fixed"] >= 2:
            ij = np.concatenate([ij, np.flatnonzero(is_fixed)[None, :2]])
        b.add_pairs(name, ij, **{s.name: _declared_values(rng, s, ij.shape[0]) for s in specs if s.per == "pair"})
    for s in specs:
        if s.per == "particle":
            v = _declared_values(rng, s, n)
            particle_arrays[s.name] = np.where((rng.random(n) < 0.5).reshape((n,) + (1,) * len(s.shape)), v,
                                               s.default)
        elif s.per == "model":
            b.set_term_data(name, **{s.name: _declared_values(rng, s, 1)[0]})


def random_scene(rng, n: int = 8, *, springs: int = 12, damping: bool = True, gravitational: int = 3,
                 drag: bool = True, fixed: int = 2, gravity: float = -9.81, ke=(20.0, 200.0),
                 fixed_pairs: bool = True, duplicate: bool = True, pair_epsilon: float = 1e-9,
                 G=(0.5, 2.0), speed: float = 1.0, select=None):
    """A small random scene exercising every registered force term (:data:`springsim.forces.FORCE_TERMS`).

    The built-in terms have tuned distributions (below); any other term gets random data from its declared
    arrays (3 random pairs and one between fixed particles, values for about half the particles, per-model
    values in each spec's sample range), drawn after the built-in ones, so the built-in terms' data of a seed
    stay the same when terms are registered.

    Parameters
    ----------
    rng : numpy.random.Generator
    n : int
        Particles, spread in a cube of side 2 m with random velocities [m/s].
    springs : int
        Random springs; about half damped when ``damping``; rest lengths mix "initial
        distance" (None) and random values.
    gravitational : int
        Random gravitational pairs with G uniform in the range ``G`` [N m^2/kg^2].
    drag : bool
        Give about half the particles a drag coefficient.
    fixed : int
        Number of fixed particles (at least 2 when ``fixed_pairs``).
    fixed_pairs : bool
        Add one spring and one gravitational pair between two fixed particles.
    duplicate : bool
        Repeat the first spring (duplicates must sum).
    ke : (float, float)
        Stiffness range [N/m].
    speed : float
        Initial velocities are uniform in [-speed, speed] [m/s].
    select : callable, optional
        A predicate on force-term classes: only the terms it accepts get data (gravity is 0 without
        ``ForceGravity``). Tests pick terms by their declared properties, e.g. ``select=internal`` (no external
        forces) or ``select=conservative``.

    Returns
    -------
    Model
    """
    from springsim.forces import FORCE_TERMS

    terms = {name: cls for name, cls in FORCE_TERMS.items() if select is None or select(cls)}
    b = ModelBuilder(gravity=gravity if "gravity" in terms else 0.0, pair_epsilon=pair_epsilon)
    # a jittered lattice keeps every pair well separated (no accidental near-degenerate pairs)
    side = int(np.ceil(n ** (1 / 3)))
    grid = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)[:n]
    pos = 0.7 * grid + rng.uniform(-0.15, 0.15, (n, 3))
    vel = rng.uniform(-speed, speed, (n, 3))
    mass = rng.uniform(0.5, 2.0, n)
    o = dict(springs=springs, damping=damping, gravitational=gravitational, ke=ke, G=G, duplicate=duplicate,
             drag=drag, terms=terms, fixed=fixed, fixed_pairs=fixed_pairs)
    arrays = {}
    for name, make in RANDOM_PARTICLES.items():
        if name in terms:
            arrays.update(make(rng, n, o))
    is_fixed = np.zeros(n, dtype=bool)
    is_fixed[rng.choice(n, size=fixed, replace=False)] = True

    def pairs(k):
        i = rng.integers(0, n, k)
        j = (i + rng.integers(1, n, k)) % n
        return np.stack([i, j], 1)

    o["pairs"] = pairs
    for name, make in RANDOM_PAIRS.items():
        if name in terms:
            make(rng, b, pos, is_fixed, o)
    if fixed_pairs and fixed >= 2:
        _fixed_pairs(b, np.flatnonzero(is_fixed)[:2], o)
    for name, cls in terms.items():
        if cls.data and name not in RANDOM_PAIRS and name not in RANDOM_PARTICLES:
            _declared_data(rng, b, name, cls, n, is_fixed, o, arrays)
    b.add_particles(pos, vel, mass, fixed=is_fixed, **arrays)
    return b.finalize()


def internal(cls) -> bool:
    """``random_scene(select=internal)``: only the terms whose forces are internal (no gravity, drag, ...)."""
    return not cls.external


def conservative(cls) -> bool:
    """``random_scene(select=conservative)``: only the terms with a potential (springs without ``damping``)."""
    return cls.conservative


def two_particle_scene(*, ke=0.0, kd=0.0, G=0.0, drag=0.0, gravity=0.0, rest_length=0.7,
                       q=((0.1, -0.2, 0.3), (0.9, 0.4, -0.1)), qd=((0.3, -0.5, 0.2), (-0.4, 0.1, 0.6)),
                       masses=(1.3, 0.7), pair_epsilon=1e-9):
    """The seed's two-particle cases: one spring (ke, kd), one gravitational pair (G) and drag."""
    b = ModelBuilder(gravity=gravity, pair_epsilon=pair_epsilon)
    b.add_particles(np.array(q, float), np.array(qd, float), np.array(masses), drag=drag)
    if ke or kd:
        b.add_spring(0, 1, ke=ke, kd=kd, rest_length=rest_length)
    if G:
        b.add_gravitational(0, 1, G=G)
    return b.finalize()


def fd_jacobians(terms, q, qd, h: float = 1e-6, h_qd: float | None = None):
    """Central finite differences ``(dF/dq, dF/dqd)``, each (3N, 3N), of the total force of ``terms``.

    ``h`` is the step in q [m], ``h_qd`` the step in qd [m/s] (default ``h``).
    """
    n = q.shape[0]
    out = []
    for which, h in ((0, h), (1, h if h_qd is None else h_qd)):
        J = np.zeros((3 * n, 3 * n))
        for k in range(3 * n):  # loop over DOFs of a tiny test scene
            x = [q.copy(), qd.copy()]
            x[which].reshape(-1)[k] += h
            fp = eval_forces(terms, x[0], x[1]).reshape(-1)
            x[which].reshape(-1)[k] -= 2 * h
            fm = eval_forces(terms, x[0], x[1]).reshape(-1)
            J[:, k] = (fp - fm) / (2 * h)
        out.append(J)
    return out[0], out[1]


def rel_err(a, b, floor: float = 1e-300) -> float:
    """``|a - b| / max(|b|, floor)`` in the Frobenius / 2-norm."""
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)) / max(np.linalg.norm(b), floor))


def assert_matches_fd(J, F, rtol: float) -> None:
    """An analytic Jacobian ``J`` against finite differences ``F``: both zero, or ``rel_err(J, F) <= rtol``."""
    if np.linalg.norm(F) == 0.0:
        assert np.linalg.norm(J) == 0.0
    else:
        assert rel_err(J, F) <= rtol


def damped_chain(stiffness_scale: float = 1.0):
    """A small smooth problem: 3 free particles hanging from a fixed one by damped springs, with drag.

    Stiffnesses are ``stiffness_scale * (200, 150, 300, 50)`` N/m; masses 0.3-0.5 kg.
    """
    b = ModelBuilder(gravity=-9.81)
    b.add_particle((0.0, 0.0, 0.0), mass=1.0, fixed=True)
    b.add_particles(np.array([[0.8, 0.3, -0.4], [1.5, -0.2, -1.1], [2.4, 0.4, -1.3]]),
                    np.array([[1.0, -2.0, 0.5], [-1.5, 0.5, 2.0], [0.3, 1.0, -1.0]]), [0.3, 0.5, 0.4], drag=0.1)
    b.add_springs([[0, 1], [1, 2], [2, 3], [0, 2]], stiffness_scale * np.array([200.0, 150.0, 300.0, 50.0]),
                  [1.0, 0.5, 0.8, 0.2], [0.6, 0.7, 0.8, 1.5])
    return b.finalize()


#: Order-test setting: the soft damped chain over [0, ORDER_T] s, compared every ORDER_EVERY s.
ORDER_SCALE, ORDER_T, ORDER_EVERY = 0.1, 0.6, 0.2


@functools.lru_cache(maxsize=None)
def _chain_reference():
    model = damped_chain(ORDER_SCALE)
    times = np.arange(0, int(round(ORDER_T / ORDER_EVERY)) + 1) * ORDER_EVERY
    return model, reference_trajectory(model, times)


def observed_errors(name: str, hs, **options) -> np.ndarray:
    """Max |q - q_ref| and |qd - qd_ref| of integrator ``name`` at each step size of ``hs``.

    Errors are taken at t = 0.2, 0.4, 0.6 s on ``damped_chain(0.1)`` against a Radau
    reference (rtol 1e-10); ``hs`` must divide 0.2 s.
    """
    from springsim import simulate
    from springsim.integrators import INTEGRATORS, make_integrator

    options = {k: v for k, v in options.items() if k not in INTEGRATORS[name].unused_options}
    model, ref = _chain_reference()
    errs = []
    for h in hs:
        tr = simulate(model, make_integrator(name, model, **options), h, int(round(ORDER_T / h)),
                      frame_every=int(round(ORDER_EVERY / h)))
        assert np.allclose(tr.t, ref.t)
        errs.append(max(np.abs(tr.q - ref.q).max(), np.abs(tr.qd - ref.qd).max()))
    return np.array(errs)


def run_cli(capsys, *argv):
    """``springsim`` with ``argv`` in this process: ``(exit status, stdout, stderr)``."""
    from springsim import cli

    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(capsys, *argv, code=2):
    """Run the CLI and check: the exit status, exactly one line on stderr, no traceback; return that line."""
    got, _, err = run_cli(capsys, *argv)
    assert got == code, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]
