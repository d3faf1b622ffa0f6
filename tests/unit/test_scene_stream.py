"""A scene file read in pieces (springsim.scene.yaml_stream) and built in parts (springsim.distributed.scene_stream),
against a whole load. One rank here (a stand-in communicator, no MPI); 2 and 3 ranks in tests/distributed."""

from __future__ import annotations

import os

import numpy as np
import pytest
import yaml
from helpers import TWO_CLOTHS_YAML, assert_same_part, mixed_scene_yaml

import springsim.scene.yaml_stream as ys
from springsim.distributed.scene import model_part
from springsim.distributed.scene_stream import streamed_part
from springsim.errors import SceneError
from springsim.model.topology import pin_boxes, pin_mask
from springsim.scene import load_scene
from springsim.scene.shipped import shipped_scene
from springsim.scene.yaml_io import _Loader

LISTS = ("particles", "springs", "gravitational")
LISTED = ["small_cloth", "three_body", "spring", "stiff_chain", "damped_spring"]


class OneRank:
    """The collective calls streamed_part makes, on one rank."""

    def Get_rank(self):
        return 0

    def Get_size(self):
        return 1

    def allgather(self, x):
        return [x]

    def alltoall(self, xs):
        return list(xs)

    def bcast(self, x, root=0):
        return x

    def allreduce(self, x):
        return x


@pytest.fixture
def mixed(tmp_path):
    p = tmp_path / "mixed.yaml"
    p.write_text(mixed_scene_yaml())
    return p


def _whole(path) -> dict:
    return yaml.load(open(path).read(), Loader=_Loader)


# -- reading in pieces ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("chunk", [1, 3, 1000])
@pytest.mark.parametrize("name", ["mixed", "small_cloth", "three_body"])
def test_item_chunks_are_the_whole_loads_items(name, chunk, mixed):
    path = mixed if name == "mixed" else shipped_scene(name)
    doc = _whole(path)
    o = ys.outline(path, LISTS)
    lists = {k: v for k, v in doc.items() if k in o.counts}
    assert o.counts == {k: len(v) for k, v in lists.items()}
    assert {k: v for k, v in o.doc.items() if k not in o.counts} == {k: v for k, v in doc.items() if k not in lists}
    got = {}
    for key, start, items in ys.item_chunks(o, chunk):
        assert start == len(got.get(key, [])) and 0 < len(items) <= chunk
        got.setdefault(key, []).extend(items)
    assert got == {k: v for k, v in lists.items() if v}


def test_a_file_changed_between_the_passes_is_an_error(mixed):
    o = ys.outline(mixed, LISTS)
    mixed.write_text(mixed.read_text().replace("mass: 0.50", "mass: 0.55"))
    with pytest.raises(SceneError, match="changed while it was read"):
        list(ys.item_chunks(o))


@pytest.mark.parametrize("text, match", [
    ("particles:\n  - {pos: &p [0, 0, 0], mass: 1}\nx-later: *p\n", r"an alias \(\*p\) to an anchor inside an item list"),
    ("<<: {name: a}\nparticles: [{pos: [0, 0, 0], mass: 1}]\n", "plain keys|YAML error"),
    ("", "empty scene file"),
    ("- 1\n- 2\n", "the top level must be a mapping"),
    ("name: a\nname: b\n", "duplicate key 'name'"),
    ("particles: [{pos: [0, 0, 0], mass: 1}\n", "YAML syntax error at line"),
])
def test_outline_errors_are_one_line(tmp_path, text, match):
    p = tmp_path / "s.yaml"
    p.write_text(text)
    with pytest.raises(SceneError, match=match) as e:
        ys.outline(p, LISTS)
    assert "\n" not in str(e.value)


def test_anchors_within_and_between_items_are_followed(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text("x-v: &v [0, 1, 0]\nparticles:\n  - {pos: &p [0, 0, 0], vel: *v, mass: 1}\n  - {pos: *p, mass: 2}\n")
    items = [it for _, _, chunk in ys.item_chunks(ys.outline(p, LISTS), 1) for it in chunk]
    assert items == [{"pos": [0, 0, 0], "vel": [0, 1, 0], "mass": 1}, {"pos": [0, 0, 0], "mass": 2}]


def test_load_scene_without_building(mixed):
    s = load_scene(mixed, build=False)
    assert s.model is None and s.generator is None and s.stream["outline"].counts == {
        "springs": 71, "particles": 40, "gravitational": 13}
    whole = load_scene(mixed)
    assert (s.sha256, s.name, s.config, s.plot) == (whole.sha256, whole.name, whole.config, whole.plot)
    g = load_scene(shipped_scene("cloth_16"), build=False)  # one generator block: generated in parts
    assert g.model is None and g.generator is not None and g.stream is None
    assert g.sha256 == load_scene(shipped_scene("cloth_16")).sha256


def test_a_scene_with_lists_and_generator_blocks_is_outlined(tmp_path):
    """Generator blocks beside item lists: their values checked with the outline (errors named as in the file),
    the particles they create counted (the plot's particle id may name one)."""
    p = tmp_path / "s.yaml"
    p.write_text("solver: {type: implicit_euler, timestep: 0.01}\ncloth: {nx: 3, ny: 3}\n"
                 "particles: [{pos: [5, 5, 5], mass: 1}]\nplot: {particle_id: 9, dof: 2}\n")
    s = load_scene(p, build=False)
    assert s.model is None and s.stream["generated"] == ("cloth", 9) and len(s.stream["cloths"]) == 1
    p.write_text("solver: {type: implicit_euler, timestep: 0.01}\ncloth: [{nx: 3, ny: 3}, {nx: 3, ny: 3, ke: -1}]\n"
                 "particles: [{pos: [5, 5, 5], mass: 1}]\n")
    with pytest.raises(SceneError) as e:
        load_scene(p, build=False)
    assert (e.value.path, e.value.message) == ("cloth[1].ke", "must be >= 0, got -1")


# -- built in parts ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("chunk", [2, 1 << 16])
@pytest.mark.parametrize("name", ["mixed", "mixed_cloths", "two_cloths"] + LISTED)
def test_streamed_part_is_the_whole_models_part(name, chunk, mixed, monkeypatch):
    monkeypatch.setattr(ys, "CHUNK_ITEMS", chunk)
    if name != "mixed":
        mixed.write_text(mixed_scene_yaml(cloths=True) if name == "mixed_cloths" else TWO_CLOTHS_YAML)
    path = mixed if name in ("mixed", "mixed_cloths", "two_cloths") else shipped_scene(name)
    whole = load_scene(path).model
    got, ref = streamed_part(load_scene(path, build=False), OneRank()), model_part(whole, 1, 0)
    assert got.model_fingerprint == whole.fingerprint()
    assert_same_part(got, ref)


@pytest.mark.parametrize("edit, path", [
    (("stiffness: 131.0", "stiffness: -3.0"), "springs[31].stiffness"),             # a value (builder's check)
    (("mass: 0.60", "mass: heavy"), "particles[1].mass"),                           # a type (item check)
    (("particle_ids: [5,", "particle_ids: [500,"), None),                           # an id out of range
    (("G: 0.5, softening: 0.05", "G: 0.5, softening: 1.0e-200"), "gravitational"),  # computed-value rule
    (("{box: [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]}", "{box: [[9, 9, 9], [10, 10, 10]]}"), "pin[1].box"),
    (("pin: [7,", "pin: [700,"), "pin[0]"),
])
def test_errors_name_the_item_as_a_whole_load_does(edit, path, mixed, monkeypatch):
    text = mixed.read_text()
    assert edit[0] in text
    mixed.write_text(text.replace(edit[0], edit[1], 1))
    monkeypatch.setattr(ys, "CHUNK_ITEMS", 4)
    with pytest.raises(SceneError) as whole:
        load_scene(mixed)
    with pytest.raises(SceneError) as got:
        streamed_part(load_scene(mixed, build=False), OneRank())
    assert (got.value.path, got.value.message) == (whole.value.path, whole.value.message)
    assert path is None or got.value.path.startswith(path)


# -- pins over a block of particles -----------------------------------------------------------------------------------
@pytest.mark.parametrize("pin", [[3, 9], 4, [1, {"box": [[0, 0, 0], [0.45, 1, 1]]}, 8], {"box": [[0, 0, 0], [1, 1, 1]]},
                                 np.array([2, 5]), range(3, 7)])
def test_pin_mask_of_a_block_is_the_slice_of_the_whole(pin):
    q = np.stack([np.linspace(0, 1, 10), np.full(10, 0.5), np.full(10, 0.5)], axis=1)
    whole = pin_mask(pin, 10, positions=q)
    for lo, hi in [(0, 4), (4, 10), (2, 2)]:
        assert np.array_equal(pin_mask(pin, 10, positions=q[lo:hi], rows=(lo, hi)), whole[lo:hi])
    assert len(pin_boxes(pin)) == (sum(isinstance(p, dict) for p in pin) if isinstance(pin, list) else
                                   int(isinstance(pin, dict)))


def test_only_regular_files_are_outlined(tmp_path):
    """The reader of pieces refuses what a whole load refuses, before opening it (a FIFO would block): one opener
    of scene files serves both (springsim.scene._yaml.open_scene_file)."""
    with pytest.raises(SceneError, match="is a directory, not a scene file"):
        ys.outline(tmp_path, LISTS)
    fifo = tmp_path / "s.yaml"
    os.mkfifo(fifo)
    with pytest.raises(SceneError, match="not a regular file"):
        load_scene(fifo, build=False)
