"""ModelBuilder validation through the Python API: every bad input is a one-line ``SceneError`` naming its path."""

import numpy as np
import pytest

from springsim.errors import SceneError
from springsim.model.builder import ModelBuilder


def _base():
    """A builder with three free particles at the unit vectors."""
    b = ModelBuilder()
    b.add_particles(np.eye(3), None, 1.0)
    return b


# (case id, mutation of the three-particle builder, expected path, fragment of the message)
CASES = [
    ("self_spring", lambda b: b.add_spring(1, 1, 10.0), "springs[0].particle_ids", "two different particles"),
    ("self_spring_bulk", lambda b: b.add_springs([[0, 1], [2, 2]], 10.0), "springs[1].particle_ids",
     "two different particles"),
    ("self_gravitational", lambda b: b.add_gravitational(2, 2, 1.0), "gravitational[0].particle_ids",
     "two different particles"),
    ("id_too_large", lambda b: b.add_spring(0, 3, 10.0), "springs[0].particle_ids", "out of range [0, 3)"),
    ("id_negative", lambda b: b.add_springs([[0, 1], [-1, 0]], 10.0), "springs[1].particle_ids", "out of range"),
    ("grav_id_out_of_range", lambda b: b.add_gravitational(0, 7, 1.0), "gravitational[0].particle_ids",
     "out of range"),
    ("id_fractional", lambda b: b.add_springs([[0, 1.5]], 10.0), "springs.particle_ids", "must be integers"),
    ("id_nan", lambda b: b.add_springs([[0, np.nan]], 10.0), "springs.particle_ids", "must be integers"),
    ("id_string", lambda b: b.add_springs([["a", "b"]], 10.0), "springs.particle_ids", "must be integers"),
    ("id_bool", lambda b: b.add_springs(np.array([[True, False]]), 10.0), "springs.particle_ids",
     "must be integers"),
    ("id_none", lambda b: b.add_gravitationals([[0, None]], 1.0), "gravitational.particle_ids", "must be integers"),
    ("pos_nan", lambda b: b.add_particle((0.0, np.nan, 0.0)), "particles[3].pos", "must be finite"),
    ("pos_inf_bulk", lambda b: b.add_particles([[0, 0, 0], [0, 0, -np.inf]]), "particles[4].pos", "must be finite"),
    ("vel_inf", lambda b: b.add_particle((0, 0, 0), vel=(np.inf, 0, 0)), "particles[3].vel", "must be finite"),
    ("mass_zero", lambda b: b.add_particle((0, 0, 0), mass=0.0), "particles[3].mass", "must be > 0"),
    ("mass_negative", lambda b: b.add_particle((0, 0, 0), mass=-2.0), "particles[3].mass", "must be > 0"),
    ("mass_nan", lambda b: b.add_particle((0, 0, 0), mass=np.nan), "particles[3].mass", "must be finite"),
    ("drag_negative", lambda b: b.add_particle((0, 0, 0), drag=-1.0), "particles[3].drag", "must be >= 0"),
    ("stiffness_negative", lambda b: b.add_spring(0, 1, -1.0), "springs[0].stiffness", "must be >= 0"),
    ("stiffness_inf", lambda b: b.add_spring(0, 1, np.inf), "springs[0].stiffness", "must be finite"),
    ("damping_negative", lambda b: b.add_spring(0, 1, 1.0, -0.5), "springs[0].damping", "must be >= 0"),
    ("damping_nan", lambda b: b.add_springs([[0, 1], [1, 2]], 1.0, [0.0, np.nan]), "springs[1].damping",
     "must be finite"),
    ("rest_length_negative", lambda b: b.add_spring(0, 1, 1.0, 0.0, -1.0), "springs[0].rest_length", ">= 0"),
    ("rest_length_inf", lambda b: b.add_spring(0, 1, 1.0, 0.0, np.inf), "springs[0].rest_length", "finite"),
    ("G_negative", lambda b: b.add_gravitational(0, 1, -1.0), "gravitational[0].G", "must be >= 0"),
    ("G_nan", lambda b: b.add_gravitational(0, 1, np.nan), "gravitational[0].G", "must be finite"),
    ("pos_wrong_width", lambda b: b.add_particles(np.zeros((2, 2))), "particles.pos", "shape (n, 3)"),
    ("pos_2_vector", lambda b: b.add_particle((0.0, 1.0)), "particles.pos", "shape (n, 3)"),
    ("pos_string", lambda b: b.add_particle(("a", 0, 0)), "particles.pos", "must be numeric"),
    ("pos_ragged", lambda b: b.add_particles([[0, 1, 2], [2]]), "particles.pos", "must be numeric"),
    ("vel_wrong_rows", lambda b: b.add_particles(np.zeros((2, 3)), np.zeros((3, 3))), "particles.vel",
     "2 rows"),
    ("mass_wrong_length", lambda b: b.add_particles(np.zeros((2, 3)), None, [1.0, 2.0, 3.0]), "particles.mass",
     "shape (2,)"),
    ("pairs_wrong_width", lambda b: b.add_springs([[0, 1, 2]], 1.0), "springs.particle_ids", "shape (n, 2)"),
    ("pairs_ragged", lambda b: b.add_springs([[0, 1], [2]], 1.0), "springs.particle_ids", "shape (n, 2)"),
    ("stiffness_wrong_length", lambda b: b.add_springs([[0, 1], [1, 2]], [1.0, 2.0, 3.0]), "springs.stiffness",
     "shape (2,)"),
    ("stiffness_string", lambda b: b.add_spring(0, 1, "stiff"), "springs.stiffness", "must be numeric"),
    ("radius_negative", lambda b: b.add_particle((0, 0, 0), radius=-1.0), "particles[3].radius", ">= 0"),
    ("gravity_nan", lambda b: setattr(b, "gravity", np.nan), "solver.gravity", "must be finite"),
    ("gravity_string", lambda b: setattr(b, "gravity", "down"), "solver.gravity", "must be a number"),
    ("pair_epsilon_zero", lambda b: setattr(b, "pair_epsilon", 0.0), "pair_epsilon", "must be > 0"),
    ("up_axis_unknown", lambda b: setattr(b, "up_axis", "w"), "up_axis", "must be one of x, y, z"),
    ("up_axis_int", lambda b: setattr(b, "up_axis", 3), "up_axis", "must be x, y, z or 0, 1, 2, got 3"),
]


@pytest.mark.parametrize("mutate, path, fragment", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_raises_scene_error(mutate, path, fragment):
    """The bad input raises SceneError (a ValueError) with a one-line 'path: message' naming the field."""
    b = _base()
    with pytest.raises(SceneError) as ei:
        mutate(b)
        b.finalize()
    e = ei.value
    assert isinstance(e, ValueError)
    assert e.path == path
    assert str(e).startswith(f"{path}: ")
    assert fragment in str(e)
    assert "\n" not in str(e)


def test_first_offending_item_is_named():
    """With several bad springs the error names the first one, counted across bulk calls."""
    b = _base()
    b.add_springs([[0, 1], [1, 2]], 5.0)
    b.add_springs([[0, 2], [0, 1], [1, 2]], [5.0, -1.0, -2.0])
    with pytest.raises(SceneError, match=r"^springs\[3\]\.stiffness: must be >= 0, got -1$"):
        b.finalize()


def test_valid_edge_values_are_accepted():
    """Zero stiffness, damping, G and rest length, integral float ids and fixed-only springs are valid."""
    b = _base()
    b.add_particle((0, 0, 0), fixed=True)
    b.add_particle((1, 1, 1), fixed=True)
    b.add_springs(np.array([[0.0, 1.0]]), 0.0, 0.0, 0.0)
    b.add_spring(3, 4, 10.0)
    b.add_gravitational(0, 2, 0.0)
    m = b.finalize()
    assert m.spring_count == 2 and m.gravitational_count == 1
    np.testing.assert_array_equal(m.spring_indices, [[0, 1], [3, 4]])


def test_duplicate_springs_are_allowed():
    """Two springs between the same pair are valid input (their forces add up)."""
    b = _base()
    b.add_springs([[0, 1], [1, 0]], [3.0, 4.0])
    assert b.finalize().spring_count == 2


def test_empty_builder_finalizes():
    """A builder with nothing in it gives an empty but valid model."""
    m = ModelBuilder().finalize()
    assert m.particle_count == 0 and m.dof_count == 0
