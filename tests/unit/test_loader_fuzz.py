"""Property tests: whatever the YAML, the only exception that escapes ``load_scene`` is ``SceneError``."""

import contextlib
import os
import copy

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from springsim import SceneError
from springsim.scene import load_scene, parse_scene, yaml_io

VALID = yaml.safe_load("""
solver: {type: implicit_euler, timestep: 0.01, gravity: -9.81, steps: 3, newton_tol: 1.0e-6}
particles:
  - {pos: [0, 0, 1], vel: [0, 0, 0], mass: 0.1, fixed: true, radius: 0.01}
  - {pos: [0, 0, 0], mass: 0.2, drag: 0.1}
  - {pos: [1, 0, 0], mass: 0.3}
springs:
  - {particle_ids: [0, 1], stiffness: 100.0, damping: 0.5, rest_length: 1.0}
  - {particle_ids: [1, 2], stiffness: 50.0}
gravitational:
  - {particle_ids: [1, 2], G: 1.0}
cloth: {nx: 2, ny: 3, spacing: 0.1, mass: 0.01, ke: 10.0, pin: edge}
plot: {particle_id: 1, dof: 2, y_range: [-1, 1]}
""")

SETTINGS = settings(max_examples=int(os.environ.get("SPRINGSIM_FUZZ_EXAMPLES", 150)), deadline=None, suppress_health_check=[HealthCheck.too_slow])

scalars = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
    st.sampled_from(["implicit_euler", "direct", "exact", "edge", "xy", "z", 0, 1, 2, -1, 3, 0.5, 1e300]),
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4),
                            st.dictionaries(st.one_of(st.text(max_size=6), st.sampled_from(list(VALID))),
                                            inner, max_size=4)),
    max_leaves=12,
)


@contextlib.contextmanager
def _small_generators():
    """Cap generated cloths at 10^4 particles so random sizes stay fast (the cap itself is tested)."""
    old = yaml_io.MAX_GENERATED_PARTICLES
    yaml_io.MAX_GENERATED_PARTICLES = 10_000
    try:
        yield
    finally:
        yaml_io.MAX_GENERATED_PARTICLES = old


def _check(load, arg) -> None:
    with _small_generators():
        try:
            load(arg)
        except SceneError as e:
            assert "\n" not in str(e)


def _load_text(text: str) -> None:
    _check(load_scene, text)


def _paths(doc, prefix=()):
    """Every (container, key) location in a nested document."""
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield prefix + (k,)
            yield from _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for k, v in enumerate(doc):
            yield prefix + (k,)
            yield from _paths(v, prefix + (k,))


PATHS = list(_paths(VALID))


def _parent(doc, path):
    for k in path[:-1]:
        doc = doc[k]
    return doc


@SETTINGS
@given(values)
def test_random_documents(doc):
    """Random YAML documents (dumped, then loaded) never raise anything but SceneError."""
    _load_text(yaml.safe_dump(doc))


@SETTINGS
@given(st.text(max_size=80))
def test_random_text(text):
    """Arbitrary text, including YAML syntax errors, never raises anything but SceneError."""
    _load_text(text)


@SETTINGS
@given(st.lists(st.tuples(st.sampled_from(PATHS), st.sampled_from(["delete", "replace"]), values),
                min_size=1, max_size=3))
def test_mutated_valid_scene(mutations):
    """Deleting keys or replacing values of a valid scene with random data only ever raises SceneError."""
    doc = copy.deepcopy(VALID)
    for path, op, value in mutations:
        try:
            parent = _parent(doc, path)
            key = path[-1]
            parent[key]
        except (KeyError, IndexError, TypeError):
            continue
        if op == "delete":
            del parent[key]
        else:
            parent[key] = value
    _check(parse_scene, doc)


@SETTINGS
@given(st.sampled_from(["springs", "gravitational"]), st.integers(0, 1), st.integers(-(2**65), 2**65))
def test_out_of_range_ids(group, slot, pid):
    """Any integer particle id is either valid or rejected with a SceneError."""
    doc = copy.deepcopy(VALID)
    doc[group][0]["particle_ids"][slot] = pid
    try:
        parse_scene(doc)
    except SceneError as e:
        assert "particle_ids" in str(e)


def test_generator_size_limit():
    """A generator block beyond MAX_GENERATED_PARTICLES is a SceneError, not a memory error."""
    with _small_generators():
        try:
            load_scene("solver: {type: midpoint, timestep: 0.1}\ncloth: {nx: 1000, ny: 1000}")
        except SceneError as e:
            assert "MAX_GENERATED_PARTICLES" in str(e)
        else:
            raise AssertionError("no SceneError")
