"""Pinning: every form of ``pin`` (names, indices, {i, j}, boxes, lists), fixing and freeing particles after
``add_cloth_grid`` (``set_fixed``, ``fix_box``, ``pin_cloth``), the top-level ``pin:`` block, and the canonical
spring coefficient names with their aliases (``stiffness``/``ke``, ``damping``/``kd``)."""

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import springsim as ss
from springsim import ModelBuilder, SceneError
from springsim.errors import SceneTypeError
from springsim.model import ClothGrid
from springsim.model.builder import COEFFICIENT_ALIASES
from springsim.model.topology import PIN_NAMES, cloth_pin_mask
from springsim.scene import benchmark_cloth, load_scene
from springsim.scene.gallery import benchmark_cloth_grid

HEAD = "solver: {type: implicit_euler, timestep: 0.01}\n"
NX, NY = 4, 3  # local index j*4 + i:  j = 0: 0 1 2 3 | j = 1: 4 5 6 7 | j = 2: 8 9 10 11

#: The particles each name pins on the 4 x 3 grid, written out.
EXPECTED = {
    "none": [],
    "edge": [0, 1, 2, 3],
    "bottom": [0, 1, 2, 3],
    "top": [8, 9, 10, 11],
    "left": [0, 4, 8],
    "right": [3, 7, 11],
    "bottom-left": [0],
    "bottom-right": [3],
    "top-left": [8],
    "top-right": [11],
    "corners": [0, 3],
    "all-corners": [0, 3, 8, 11],
    "ends": [0, 1, 2, 3, 8, 9, 10, 11],
}


def _grid_fixed(pin, *, offset: int = 1, **kw) -> np.ndarray:
    """Local indices of the fixed particles of a 4 x 3 grid added after ``offset`` free particles."""
    b = ModelBuilder()
    if offset:
        b.add_particles(np.full((offset, 3), 9.0), mass=1.0)
    r = b.add_cloth_grid(NX, NY, pin=pin, **kw)
    m = b.finalize()
    assert r == range(offset, offset + NX * NY)
    assert not m.particle_fixed[:offset].any()
    return np.flatnonzero(m.particle_fixed[offset:])


def _yaml_fixed(pin_yaml: str, extra: str = "") -> np.ndarray:
    m = load_scene(HEAD + f"particles: [{{pos: [9, 9, 9], mass: 1}}]\ncloth: {{nx: {NX}, ny: {NY}, size: [3, 2], "
                          f"pin: {pin_yaml}{extra}}}\n").model
    assert not m.particle_fixed[0]
    return np.flatnonzero(m.particle_fixed[1:])


def _scene_error(text: str) -> SceneError:
    with pytest.raises(SceneError) as info:
        load_scene(HEAD + text)
    return info.value


def _one_line(e: SceneError, path: str, fragment: str) -> None:
    msg = str(e)
    assert "\n" not in msg
    assert e.path == path, msg
    assert msg.startswith(f"{path}: "), msg
    assert fragment in msg, msg


# -- names ------------------------------------------------------------------------------------------
def test_every_name_has_an_expectation():
    """The table below covers every accepted name (a new name needs its expectation)."""
    assert set(EXPECTED) == set(PIN_NAMES)


@pytest.mark.parametrize("name", list(EXPECTED))
def test_named_pins_on_a_non_square_grid(name):
    """Each edge and corner name pins exactly its particles, through the builder, the topology function and YAML."""
    expected = EXPECTED[name]
    np.testing.assert_array_equal(_grid_fixed(name), expected)
    np.testing.assert_array_equal(np.flatnonzero(cloth_pin_mask(NX, NY, name)), expected)
    np.testing.assert_array_equal(_yaml_fixed(name), expected)


@pytest.mark.parametrize("plane, axes", [("xy", (0, 1)), ("xz", (0, 2)), ("yz", (1, 2))])
def test_names_follow_the_grid_axes(plane, axes):
    """bottom/top are the lowest/highest rows along the plane's second axis, left/right along its first."""
    a, b = axes
    builder = ModelBuilder()
    builder.add_cloth_grid(NX, NY, plane=plane, size=(3.0, 2.0), pin="none")
    q = builder.finalize().particle_q
    sel = {name: np.asarray(EXPECTED[name]) for name in ("bottom", "top", "left", "right", "top-right")}
    np.testing.assert_array_equal(q[sel["bottom"], b], q[:, b].min())
    np.testing.assert_array_equal(q[sel["top"], b], q[:, b].max())
    np.testing.assert_array_equal(q[sel["left"], a], q[:, a].min())
    np.testing.assert_array_equal(q[sel["right"], a], q[:, a].max())
    np.testing.assert_array_equal(q[sel["top-right"]][0, [a, b]], [3.0, 2.0])


def test_legacy_names_keep_their_meaning():
    """``edge``, ``corners`` and ``ends`` (the only names before) are row j = 0, its two corners, rows 0 and ny-1."""
    assert list(_grid_fixed("edge")) == list(_grid_fixed("bottom"))
    assert list(_grid_fixed("corners")) == list(_grid_fixed(["bottom-left", "bottom-right"]))
    assert list(_grid_fixed("ends")) == list(_grid_fixed(["bottom", "top"]))
    assert list(_grid_fixed(None)) == list(_grid_fixed("none")) == []
    b = ModelBuilder()
    b.add_cloth_grid(NX, NY)  # the default is still the edge j = 0
    np.testing.assert_array_equal(np.flatnonzero(b.finalize().particle_fixed), EXPECTED["edge"])


# -- lists, indices, {i, j} ---------------------------------------------------------------------------
@pytest.mark.parametrize("first", ["top", "left", "bottom-right", "corners"])
@pytest.mark.parametrize("second", ["right", "top-left", "ends", "none"])
def test_a_list_is_the_union(first, second):
    """A list of names pins the union of its items."""
    expected = sorted(set(EXPECTED[first]) | set(EXPECTED[second]))
    np.testing.assert_array_equal(_grid_fixed([first, second]), expected)
    np.testing.assert_array_equal(_yaml_fixed(f"[{first}, {second}]"), expected)


def test_mixed_list_of_names_indices_ij_and_box():
    """Names, local indices, {i, j} and boxes combine in one list (duplicates are harmless)."""
    pin = ["top", 5, {"i": 1, "j": 0}, {"box": [[2.9, -0.1, -1], [3.1, 0.1, 1]]}, 9]
    np.testing.assert_array_equal(_grid_fixed(pin, size=(3.0, 2.0)), [1, 3, 5, 8, 9, 10, 11])
    np.testing.assert_array_equal(_yaml_fixed("[top, 5, {i: 1, j: 0}, {box: [[2.9, -0.1, -1], [3.1, 0.1, 1]]}, 9]"),
                                  [1, 3, 5, 8, 9, 10, 11])


@pytest.mark.parametrize("pin", [[0, 5, 11], (11, 0, 5), np.array([5, 0, 11]), np.array([0, 5, 11], dtype=np.uint8),
                                 np.isin(np.arange(12), [0, 5, 11]), [np.int64(0), 5, np.int32(11)]],
                         ids=["list", "tuple", "int_array", "uint8_array", "bool_mask", "numpy_ints"])
def test_explicit_indices(pin):
    """Local indices j*nx + i as a list, tuple, integer array or boolean mask pin exactly those particles."""
    np.testing.assert_array_equal(_grid_fixed(pin), [0, 5, 11])


def test_indices_ranges_and_single_index():
    """A range, a single integer and ``{i, j}`` address grid particles; YAML lists of integers too."""
    np.testing.assert_array_equal(_grid_fixed(range(4, 8)), [4, 5, 6, 7])
    np.testing.assert_array_equal(_grid_fixed(7), [7])
    np.testing.assert_array_equal(_grid_fixed({"i": 3, "j": 1}), [7])
    np.testing.assert_array_equal(_yaml_fixed("[0, 5, 11, 5]"), [0, 5, 11])
    np.testing.assert_array_equal(_yaml_fixed("{i: 2, j: 2}"), [10])
    np.testing.assert_array_equal(_yaml_fixed("[]"), [])


# -- boxes ------------------------------------------------------------------------------------------
def test_box_selects_by_position_in_scene_coordinates():
    """A box is closed and in scene coordinates: it follows ``origin`` and ``plane``."""
    # 4 x 3 grid in xz from origin (1, 2, 3), spacing 0.5: x in {1, 1.5, 2, 2.5}, z in {3, 3.5, 4}, y = 2
    kw = {"origin": (1.0, 2.0, 3.0), "spacing": 0.5, "plane": "xz"}
    np.testing.assert_array_equal(_grid_fixed({"box": [[0, 0, 4], [9, 9, 9]]}, **kw), EXPECTED["top"])
    np.testing.assert_array_equal(_grid_fixed({"box": [[1, 2, 3], [1.5, 2, 3.5]]}, **kw), [0, 1, 4, 5])
    np.testing.assert_array_equal(_grid_fixed({"box": np.array([[2.4, 0, 0], [3, 3, 3.6]])}, **kw), [3, 7])
    m = load_scene(HEAD + "cloth: {nx: 4, ny: 3, origin: [1, 2, 3], spacing: 0.5, plane: xz, "
                          "pin: {box: [[0, 0, 4], [9, 9, 9]]}}").model
    np.testing.assert_array_equal(np.flatnonzero(m.particle_fixed), EXPECTED["top"])


BOX_ERRORS = [
    # (pin in YAML, path, fragment)
    ("{box: 3}", "cloth.pin.box", "must be [[xmin, ymin, zmin], [xmax, ymax, zmax]], got an integer 3"),
    ("{box: [[0, 0, 0]]}", "cloth.pin.box", "must be [[xmin, ymin, zmin], [xmax, ymax, zmax]]"),
    ("{box: [[0, 0, 0], [1, 1, 1], [2, 2, 2]]}", "cloth.pin.box", "must be [[xmin"),
    ("{box: [[0, 0, 0], [1, 1]]}", "cloth.pin.box[1]", "must be 3 numbers [x, y, z], got a list [1, 1]"),
    ("{box: [0, [1, 1, 1]]}", "cloth.pin.box[0]", "must be 3 numbers"),
    ("{box: [[0, 0, 0], [1, x, 1]]}", "cloth.pin.box[1][1]", "must be a number, got a string 'x'"),
    ("{box: [[0, 0, true], [1, 1, 1]]}", "cloth.pin.box[0][2]", "must be a number, got a boolean"),
    ("{box: [[0, 0, .nan], [1, 1, 1]]}", "cloth.pin.box[0][2]", "must be finite"),
    ("{box: [[0, 0, 0], [1, .inf, 1]]}", "cloth.pin.box[1][1]", "must be finite"),
    ("{box: [[0, 0, 1], [1, 1, 0]]}", "cloth.pin.box", "needs min <= max in every coordinate"),
    ("{box: [[5, 5, 5], [6, 6, 6]]}", "cloth.pin.box",
     "contains no particle (the particles span [0, 0, 0] to [3, 2, 0])"),
    ("[top, {box: [[0, 0, 1], [1, 1, 0]]}]", "cloth.pin[1].box", "needs min <= max"),
    ("{box: [[0, 0, 0], [1, 1, 1]], i: 0}", "cloth.pin",
     "a pin mapping is {box: [[xmin, ymin, zmin], [xmax, ymax, zmax]]} or {i: I, j: J}, got the keys ['box', 'i']"),
    ("{boxx: 1}", "cloth.pin", "got the keys ['boxx']"),
    ("{}", "cloth.pin", "a pin mapping is"),
]


@pytest.mark.parametrize("pin, path, fragment", BOX_ERRORS, ids=[f"box{k}" for k in range(len(BOX_ERRORS))])
def test_malformed_boxes(pin, path, fragment):
    """Every malformed box is one line naming the box (or its corner, or coordinate)."""
    _one_line(_scene_error(f"cloth: {{nx: 4, ny: 3, size: [3, 2], pin: {pin}}}"), path, fragment)


# -- errors of the other forms --------------------------------------------------------------------------
PIN_ERRORS = [
    ("topp", "cloth.pin", ("unknown pin name 'topp'; choose one of none, edge, corners, ends, bottom, top, left, "
                           "right, bottom-left, bottom-right, top-left, top-right, all-corners")),
    ("[top, left, topp]", "cloth.pin[2]", "unknown pin name 'topp'; choose one of"),
    ("Top", "cloth.pin", "unknown pin name 'Top'"),
    ("[0, 5, 12]", "cloth.pin[2]", "particle index out of range [0, 12), got 12"),
    ("[3, -1]", "cloth.pin[1]", "particle index out of range [0, 12), got -1"),
    ("[top, 99]", "cloth.pin[1]", "particle index out of range [0, 12), got 99"),
    ("12", "cloth.pin", "particle index out of range [0, 12), got 12"),
    ("[0, 123456789012345678901234567890]", "cloth.pin[1]", "particle index out of range [0, 12)"),
    ("[0, 1.5]", "cloth.pin[1]", ("must be an edge or corner name, a particle index, {box: [[xmin, ymin, zmin], "
                                  "[xmax, ymax, zmax]]} or {i: I, j: J}, got a number 1.5")),
    ("[true, false]", "cloth.pin[0]", "got a boolean True"),
    ("[[0, 1]]", "cloth.pin[0]", "got a list [0, 1]"),
    ("2.5", "cloth.pin", "got a number 2.5"),
    ("true", "cloth.pin", "got a boolean True"),
    ("{i: 4, j: 0}", "cloth.pin.i", "must be an integer in [0, 4), got 4"),
    ("[{i: 0, j: 3}]", "cloth.pin[0].j", "must be an integer in [0, 3), got 3"),
    ("{i: 0.5, j: 0}", "cloth.pin.i", "must be an integer in [0, 4), got a number 0.5"),
    ("{i: 0}", "cloth.pin", "got the keys ['i']"),
]


@pytest.mark.parametrize("pin, path, fragment", PIN_ERRORS, ids=[f"pin{k}" for k in range(len(PIN_ERRORS))])
def test_bad_pins_are_one_line_with_the_item_path(pin, path, fragment):
    """Unknown names, out-of-range indices and wrong types name the offending item of ``cloth.pin``."""
    _one_line(_scene_error(f"cloth: {{nx: 4, ny: 3, size: [3, 2], pin: {pin}}}"), path, fragment)


def test_pin_errors_name_the_block():
    """In a list of cloth blocks and in ``benchmark_cloth`` the path names the block as written."""
    _one_line(_scene_error("cloth: [{nx: 2, ny: 2}, {nx: 4, ny: 3, pin: [top, 12]}]"), "cloth[1].pin[1]",
              "out of range [0, 12)")
    _one_line(_scene_error("benchmark_cloth: {n: 3, pin: [top, topp]}"), "benchmark_cloth.pin[1]",
              "unknown pin name 'topp'")
    m = load_scene("solver: {type: linearized_implicit}\nbenchmark_cloth: {n: 3, pin: [left, right]}").model
    np.testing.assert_array_equal(np.flatnonzero(m.particle_fixed), [0, 2, 3, 5, 6, 8])


def test_builder_pin_errors():
    """The builder raises the same errors (SceneTypeError for wrong types); nothing is added on error."""
    b = ModelBuilder()
    with pytest.raises(SceneError) as info:
        b.add_cloth_grid(NX, NY, pin=np.array([0, 12]))
    _one_line(info.value, "cloth.pin[1]", "particle index out of range [0, 12), got 12")
    with pytest.raises(SceneError) as info:
        b.add_cloth_grid(NX, NY, pin=np.zeros(11, dtype=bool))
    _one_line(info.value, "cloth.pin", "a boolean mask must have shape (12,), got (11,)")
    with pytest.raises(SceneTypeError) as info:
        b.add_cloth_grid(NX, NY, pin=np.array([0.0, 1.0]))
    _one_line(info.value, "cloth.pin", "must be particle indices")
    with pytest.raises(SceneTypeError):
        b.add_cloth_grid(NX, NY, pin=object())
    assert b.particle_count == 0 and b.spring_count == 0 and b.cloth_grids == ()


# -- fixing and freeing after add_cloth_grid ---------------------------------------------------------------
def test_set_fixed_after_add_cloth_grid():
    """set_fixed fixes and frees particles by index or mask; the model's fixed mask and DOF count follow."""
    b = ModelBuilder()
    b.add_particle((5, 5, 5), mass=1.0)
    r = b.add_cloth_grid(NX, NY, pin="top")
    assert b.cloth_grids == (ClothGrid(1, NX, NY),)
    np.testing.assert_array_equal(b.set_fixed([r[0], r[3]]), [1, 4])  # the bottom corners
    np.testing.assert_array_equal(b.set_fixed(r[8], fixed=False), [9])  # free the top-left corner
    np.testing.assert_array_equal(b.set_fixed(np.array([0])), [0])
    m = b.finalize()
    expected = {0, 1, 4, 10, 11, 12}
    np.testing.assert_array_equal(np.flatnonzero(m.particle_fixed), sorted(expected))
    assert m.free_count == 13 - len(expected) and m.dof_count == 3 * (13 - len(expected))
    np.testing.assert_array_equal(m.free_particles, sorted(set(range(13)) - expected))


def test_set_fixed_with_a_mask_and_ranges():
    """A boolean mask (e.g. from ``particle_q``) and a range are accepted; the flags of others are kept."""
    b = ModelBuilder()
    r = b.add_cloth_grid(NX, NY, size=(3, 2), pin="none")
    q = b.particle_q
    assert q.shape == (12, 3) and not q.flags.writeable
    np.testing.assert_array_equal(b.set_fixed(q[:, 0] >= 2.0), [2, 3, 6, 7, 10, 11])
    np.testing.assert_array_equal(b.set_fixed(range(r.start, r.start + 2)), [0, 1])
    np.testing.assert_array_equal(b.set_fixed(range(2, 4), False), [2, 3])
    np.testing.assert_array_equal(b.set_fixed([]), [])
    np.testing.assert_array_equal(np.flatnonzero(b.finalize().particle_fixed), [0, 1, 6, 7, 10, 11])


def test_set_fixed_frees_and_zeroes_velocities():
    """Fixing a moving particle zeroes its velocity in the model; freeing keeps the given velocity."""
    b = ModelBuilder()
    flags = np.array([True, False])
    b.add_particles([[0, 0, 0], [1, 0, 0]], [[1, 2, 3], [4, 5, 6]], 1.0, fixed=flags)
    b.set_fixed(0, False)
    b.set_fixed(1)
    m = b.finalize()
    np.testing.assert_array_equal(m.particle_fixed, [False, True])
    np.testing.assert_array_equal(m.particle_qd, [[1, 2, 3], [0, 0, 0]])
    np.testing.assert_array_equal(flags, [True, False])  # the caller's array is not written to


def test_fix_box_and_pin_cloth():
    """fix_box and pin_cloth return the affected global indices and change only those flags."""
    b = ModelBuilder()
    b.add_cloth_grid(2, 2, origin=(10, 0, 0), pin="none")
    b.add_cloth_grid(NX, NY, size=(3, 2), pin="none")  # particles 4..15, x in {0, 1, 2, 3}, y in {0, 1, 2}
    np.testing.assert_array_equal(b.fix_box((-0.5, 1.5, -1), (3.5, 2.5, 1)), 4 + np.array(EXPECTED["top"]))
    np.testing.assert_array_equal(b.fix_box((-1, -1, -1), (-0.5, -0.5, -0.5)), [])
    np.testing.assert_array_equal(b.pin_cloth("left"), 4 + np.array(EXPECTED["left"]))
    np.testing.assert_array_equal(b.pin_cloth(["top-left", "top-right"], fixed=False), [12, 15])
    np.testing.assert_array_equal(b.pin_cloth("bottom", grid=0), [0, 1])
    np.testing.assert_array_equal(b.pin_cloth({"box": [[10.5, 0.5, -1], [11, 1, 1]]}, grid=b.cloth_grids[0]), [3])
    np.testing.assert_array_equal(b.fix_box((2.5, -1, -1), (3.5, 0.5, 1), fixed=False), [7])
    m = b.finalize()
    np.testing.assert_array_equal(np.flatnonzero(m.particle_fixed), [0, 1, 3, 4, 8, 13, 14])
    assert m.dof_count == 3 * (16 - 7)


@pytest.mark.parametrize("call, path, fragment", [
    (lambda b: b.set_fixed([0, 12]), "set_fixed.indices[1]", "particle index out of range [0, 12), got 12"),
    (lambda b: b.set_fixed(-1), "set_fixed.indices", "particle index out of range [0, 12), got -1"),
    (lambda b: b.set_fixed(np.ones(5, dtype=bool)), "set_fixed.indices", "a boolean mask must have shape (12,)"),
    (lambda b: b.set_fixed([0, "a"]), "set_fixed.indices[1]", "must be a particle index (an integer), got a string"),
    (lambda b: b.set_fixed([0, True]), "set_fixed.indices[1]", "must be a particle index"),
    (lambda b: b.set_fixed(0.5), "set_fixed.indices", "must be particle indices"),
    (lambda b: b.set_fixed("top"), "set_fixed.indices", "must be particle indices"),
    (lambda b: b.set_fixed(0, fixed="yes"), "set_fixed.fixed", "must be True or False"),
    (lambda b: b.fix_box((0, 0), (1, 1, 1)), "fix_box.lo", "must be 3 numbers"),
    (lambda b: b.fix_box((0, 0, 0), (1, np.nan, 1)), "fix_box.hi[1]", "must be finite"),
    (lambda b: b.fix_box((0, 0, 1), (1, 1, 0)), "fix_box", "needs lo <= hi in every coordinate"),
    (lambda b: b.pin_cloth("topp"), "pin_cloth.pin", "unknown pin name 'topp'"),
    (lambda b: b.pin_cloth("top", grid=1), "pin_cloth.grid", "no cloth grid 1 (the builder has 1)"),
    (lambda b: b.pin_cloth("top", grid=ClothGrid(0, 2, 2)), "pin_cloth.grid", "is not a grid of this builder"),
    (lambda b: b.pin_cloth({"box": [[5, 5, 5], [6, 6, 6]]}), "pin_cloth.pin.box", "contains no particle"),
])
def test_fixing_errors(call, path, fragment):
    """Bad arguments of set_fixed, fix_box and pin_cloth are one-line SceneErrors naming the argument."""
    b = ModelBuilder()
    b.add_cloth_grid(NX, NY, size=(3, 2), pin="none")
    with pytest.raises(SceneError) as info:
        call(b)
    _one_line(info.value, path, fragment)
    assert not b.finalize().particle_fixed.any()  # nothing changed


def test_cloth_pinned_by_top_hangs():
    """A horizontal cloth pinned by ``top`` falls under gravity: the top row stays put, every other particle moves
    down, more the farther it is from the pinned row."""
    b = ModelBuilder(gravity=-9.81, up_axis="z")
    b.add_cloth_grid(5, 4, size=(1.0, 0.6), total_mass=0.2, stiffness=500.0, damping=0.5, pin="top")
    model = b.finalize()
    pinned = np.flatnonzero(model.particle_fixed)
    np.testing.assert_array_equal(pinned, [15, 16, 17, 18, 19])
    traj = ss.simulate(model, ss.make_integrator("implicit_euler", model), dt=0.01, steps=20)
    q = traj.q[-1]
    np.testing.assert_array_equal(q[pinned], model.particle_q[pinned])
    drop = (model.particle_q[:, 2] - q[:, 2]).reshape(4, 5)  # rows j = 0 (far) ... 3 (pinned)
    assert np.all(drop[:3] > 1e-3), drop
    assert np.all(drop[0] > drop[1]) and np.all(drop[1] > drop[2]), drop
    assert np.all(np.isfinite(traj.q))


# -- the top-level pin: block ----------------------------------------------------------------------------
def test_top_level_pin_uses_global_indices_and_boxes():
    """``pin:`` at the top level fixes scene particles (explicit or generated) by global index or box."""
    text = HEAD + ("particles: [{pos: [0, 0, 5], mass: 1}, {pos: [1, 0, 5], mass: 1}]\n"
                   "cloth: {nx: 4, ny: 3, size: [3, 2], pin: none}\n")
    m = load_scene(text + "pin: [1, {box: [[-0.5, 1.5, -1], [3.5, 2.5, 1]]}]\n").model
    np.testing.assert_array_equal(np.flatnonzero(m.particle_fixed), [1] + list(2 + np.array(EXPECTED["top"])))
    m = load_scene(text + "pin: 13\n").model
    np.testing.assert_array_equal(np.flatnonzero(m.particle_fixed), [13])
    assert not load_scene(text + "pin: null\n").model.particle_fixed.any()
    _one_line(_scene_error(text[len(HEAD):] + "pin: [0, 14]\n"), "pin[1]", "particle index out of range [0, 14), got 14")
    _one_line(_scene_error(text[len(HEAD):] + "pin: top\n"), "pin",
              "edge and corner names such as 'top' apply to a cloth block")
    _one_line(_scene_error(text[len(HEAD):] + "pin: {i: 0, j: 0}\n"), "pin", "{i: , j: } applies to a cloth block")
    _one_line(_scene_error(text[len(HEAD):] + "pin: {box: [[9, 9, 9], [9, 9, 9]]}\n"), "pin.box",
              "contains no particle (the particles span [0, 0, 0] to [3, 2, 5])")


# -- canonical names and aliases -------------------------------------------------------------------------
def _arrays(model) -> dict:
    out = {f.name: getattr(model, f.name) for f in dataclasses.fields(model)
           if isinstance(getattr(model, f.name), np.ndarray)}
    out.update({f"{term}.{name}": a for term, data in model.terms.items() for name, a in data.items()})
    return out


def _assert_same_model(m1, m2) -> None:
    a1, a2 = _arrays(m1), _arrays(m2)
    assert a1.keys() == a2.keys()
    for name in a1:
        np.testing.assert_array_equal(a1[name], a2[name], err_msg=name)
    assert m1.cloth_grids == m2.cloth_grids


SPRINGS_CANONICAL = """
particles: [{pos: [0, 0, 1], mass: 1, fixed: true}, {pos: [0, 0, 0], mass: 2}, {pos: [1, 0, 0], mass: 1}]
springs:
  - {particle_ids: [0, 1], stiffness: 100, damping: 0.5}
  - {particle_ids: [1, 2], stiffness: 30, rest_length: 0.5}
cloth:
  nx: 4
  ny: 3
  stiffness: 1000
  damping: 0.25
  stiffness_y: 2000
  damping_y: 0.5
  stiffness_shear: 300
  damping_shear: 0.125
  stiffness_bend: 40
  damping_bend: 0.0625
  pin: top
benchmark_cloth: {n: 3, stiffness: 700, damping: 0.75, stiffness_shear: 600, stiffness_bend: 50}
"""


def test_aliases_give_identical_models():
    """A scene written with ke/kd (and ke_y, kd_shear, ...) loads to exactly the model written with
    stiffness/damping, and a mix of the two spellings too."""
    canonical = load_scene("solver: {type: linearized_implicit, timestep: 0.01}\n" + SPRINGS_CANONICAL).model
    aliased_text = SPRINGS_CANONICAL
    for alias, canon in sorted(COEFFICIENT_ALIASES.items(), key=lambda kv: -len(kv[1])):
        aliased_text = re.sub(rf"\b{canon}:", f"{alias}:", aliased_text)
    assert "stiffness" not in aliased_text and "damping" not in aliased_text
    aliased = load_scene("solver: {type: linearized_implicit, timestep: 0.01}\n" + aliased_text).model
    _assert_same_model(canonical, aliased)
    mixed = SPRINGS_CANONICAL.replace("stiffness: 100,", "ke: 100,").replace("damping: 0.25", "kd: 0.25")
    _assert_same_model(canonical, load_scene("solver: {type: linearized_implicit, timestep: 0.01}\n" + mixed).model)
    assert canonical.spring_stiffness[0] == 100 and canonical.spring_damping[0] == 0.5


def test_builder_keywords_and_aliases_are_equivalent():
    """add_spring(s), add_cloth_grid and benchmark_cloth accept stiffness/damping and their aliases alike,
    positional callers included."""
    def build(spring_kw, springs_kw, cloth_kw):
        b = ModelBuilder()
        b.add_particles(np.eye(3), None, 1.0)
        b.add_spring(0, 1, **spring_kw)
        b.add_springs([[1, 2], [0, 2]], **springs_kw)
        b.add_cloth_grid(3, 3, origin=(2, 0, 0), **cloth_kw)
        return b.finalize()

    values = {"": 5.0, "_y": 6.0, "_shear": 7.0, "_bend": 8.0}
    canonical = build({"stiffness": 10.0, "damping": 0.5}, {"stiffness": [1.0, 2.0], "damping": 0.25},
                      {**{f"stiffness{s}": v for s, v in values.items()},
                       **{f"damping{s}": v / 50 for s, v in values.items()}})
    aliased = build({"ke": 10.0, "kd": 0.5}, {"ke": [1.0, 2.0], "kd": 0.25},
                    {**{f"ke{s}": v for s, v in values.items()}, **{f"kd{s}": v / 50 for s, v in values.items()}})
    _assert_same_model(canonical, aliased)
    b = ModelBuilder()
    b.add_particles(np.eye(3), None, 1.0)
    b.add_spring(0, 1, 10.0, 0.5)  # positional, as before
    b.add_springs([[1, 2], [0, 2]], [1.0, 2.0], 0.25)
    b.add_cloth_grid(3, 3, origin=(2, 0, 0), ke=5.0, kd=0.1, stiffness_y=6.0, kd_y=0.12, ke_shear=7.0,
                     damping_shear=0.14, stiffness_bend=8.0, kd_bend=0.16)
    _assert_same_model(canonical, b.finalize())
    _assert_same_model(benchmark_cloth(4, ke=1e3, kd=0.5, ke_shear=900.0, ke_bend=50.0),
                       benchmark_cloth(4, stiffness=1e3, damping=0.5, stiffness_shear=900.0, stiffness_bend=50.0))
    assert benchmark_cloth_grid(4) == benchmark_cloth_grid(4, stiffness=1e4, damping=0.0, stiffness_bend=1e2)


@pytest.mark.parametrize("alias, canon", sorted(COEFFICIENT_ALIASES.items()))
def test_both_spellings_in_a_cloth_block_are_an_error(alias, canon):
    """Giving a cloth coefficient under both spellings is one line naming both (YAML and builder)."""
    _one_line(_scene_error(f"cloth: [{{nx: 2, ny: 2}}, {{nx: 3, ny: 3, {canon}: 1, {alias}: 1}}]"), "cloth[1]",
              f"give {canon} or its alias {alias}, not both")
    with pytest.raises(SceneError) as info:
        ModelBuilder().add_cloth_grid(3, 3, **{canon: 1.0, alias: 2.0})
    _one_line(info.value, "cloth", f"give {canon} or its alias {alias}, not both")


@pytest.mark.parametrize("text, path, fragment", [
    ("springs: [{particle_ids: [0, 1], stiffness: 1}, {particle_ids: [0, 1], stiffness: 1, ke: 1}]", "springs[1]",
     "give stiffness or its alias ke, not both"),
    ("springs: [{particle_ids: [0, 1], stiffness: 1, damping: 0, kd: 0}]", "springs[0]",
     "give damping or its alias kd, not both"),
    ("springs: [{particle_ids: [0, 1], ke: -1}]", "springs[0].ke", "must be >= 0, got -1"),
    ("springs: [{particle_ids: [0, 1], stiffness: 1}, {particle_ids: [0, 1], ke: 1, kd: .nan}]", "springs[1].kd",
     "must be finite"),
    ("springs: [{particle_ids: [0, 1], ke: '1e4'}]", "springs[0].ke", "must be a number, got a string '1e4'"),
    ("springs: [{particle_ids: [0, 1], kd: 1}]", "springs[0]", "missing required key 'stiffness' (or its alias 'ke')"),
    ("springs: [{particle_ids: [0, 1], k: 1}]", "springs[0]",
     "unknown key 'k'; allowed: particle_ids, stiffness, damping, rest_length, ke, kd"),
    ("cloth: {nx: 3, ny: 3, kd_bend: -1}", "cloth.kd_bend", "must be >= 0, got -1"),
    ("cloth: {nx: 3, ny: 3, damping_y: -1}", "cloth.damping_y", "must be >= 0, got -1"),
    ("benchmark_cloth: {n: 3, ke: 1, stiffness: 1}", "benchmark_cloth", "give stiffness or its alias ke, not both"),
    ("benchmark_cloth: {n: 3, damping: -1}", "benchmark_cloth.damping", "must be >= 0"),
    ("benchmark_cloth: {n: 3, kd: -1}", "benchmark_cloth.kd", "must be >= 0"),
    ("benchmark_cloth: {n: 3, ke_bend: -2}", "benchmark_cloth.ke_bend", "must be >= 0"),
    ("benchmark_cloth: {n: 3, stiffness_shear: x}", "benchmark_cloth.stiffness_shear", "must be a number"),
])
def test_coefficient_errors_name_the_key_as_written(text, path, fragment):
    """Errors about a coefficient name it as the file spells it (alias or canonical), one line."""
    particles = "particles: [{pos: [0, 0, 0], mass: 1}, {pos: [1, 0, 0], mass: 1}]\n"
    if text.startswith("benchmark_cloth"):
        with pytest.raises(SceneError) as info:
            load_scene("solver: {type: linearized_implicit}\n" + text)
        e = info.value
    else:
        e = _scene_error(particles + text)
    _one_line(e, path, fragment)


def test_builder_spring_alias_errors():
    """The builder refuses both spellings and a missing stiffness, naming springs."""
    b = ModelBuilder()
    b.add_particles(np.eye(2, 3), None, 1.0)
    with pytest.raises(SceneError) as info:
        b.add_spring(0, 1, stiffness=1.0, ke=2.0)
    _one_line(info.value, "springs", "give stiffness or its alias ke, not both")
    with pytest.raises(SceneError) as info:
        b.add_springs([[0, 1]], 1.0, damping=0.1, kd=0.1)
    _one_line(info.value, "springs", "give damping or its alias kd, not both")
    with pytest.raises(SceneTypeError) as info:
        b.add_spring(0, 1, kd=0.1)
    _one_line(info.value, "springs.stiffness", "missing: give stiffness (or its alias ke)")
    assert b.spring_count == 0


# -- robustness and documentation --------------------------------------------------------------------------
_pin_scalars = st.one_of(st.none(), st.booleans(), st.integers(-20, 20), st.integers(-(2**70), 2**70),
                         st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=6),
                         st.sampled_from(list(PIN_NAMES)))
_pin_values = st.recursive(
    _pin_scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4),
                            st.dictionaries(st.sampled_from(["box", "i", "j", "x"]), inner, max_size=3)),
    max_leaves=10,
)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_pin_values, st.booleans())
def test_random_pins_raise_only_scene_errors(pin, top_level):
    """Whatever the pin value, in a cloth block or at the top level, the loader either loads or raises a one-line
    SceneError naming a pin path."""
    from springsim.scene import parse_scene

    doc = {"solver": {"type": "midpoint", "timestep": 0.1}, "cloth": {"nx": 4, "ny": 3, "pin": "none"}}
    if top_level:
        doc["pin"] = pin
    else:
        doc["cloth"]["pin"] = pin
    try:
        parse_scene(doc)
    except SceneError as e:
        assert "\n" not in str(e)
        assert e.path.startswith("pin" if top_level else "cloth.pin"), str(e)


DOC = Path(__file__).resolve().parents[2] / "docs" / "scene-format.md"


def test_scene_format_examples_load():
    """Every complete YAML scene shown in docs/scene-format.md loads (the pin and alias examples included)."""
    blocks = [b for b in re.findall(r"```yaml\n(.*?)```", DOC.read_text(encoding="utf-8"), flags=re.DOTALL)
              if re.search(r"^solver:", b, flags=re.MULTILINE)]
    assert len(blocks) >= 3
    for block in blocks:
        block = block.replace("nx: 512, ny: 512", "nx: 8, ny: 8")  # the big-cloth example, small here
        assert load_scene(block).model.particle_count > 0
