"""Read a YAML scene file in pieces: its small sections whole, its item lists a chunk of items at a time.

A scene's size is in its item lists: ``particles`` and the pair terms' lists (``springs``, ``gravitational``).
:func:`load_scene <springsim.scene.load_scene>` composes the whole document, a Python object per item and per
number, about ten times the bytes of the arrays they become. Here the document is read twice, never whole:

1. :func:`outline`: the small sections composed as usual; each item list consumed event by event, its items
   counted, not composed; the file's SHA-256 computed on the way.
2. :func:`item_chunks`: the item lists again, each item composed and constructed alone (PyYAML's composer fed by
   libyaml's event parser), handed over in chunks of :data:`CHUNK_ITEMS` items in document order; the file checked
   unchanged at the end (its SHA-256 again).

So memory is one chunk of items plus the anchors a document defines, and time is one event pass more than a whole
load (:func:`~springsim.scene.yaml_io.load_scene`'s own shape check is the first pass of both). The values are the
ones a whole load gives: the same loader (YAML 1.2 numbers, duplicate keys refused) constructs every item. A
distributed run reads a scene this way on one rank and sends the chunks on
(:func:`springsim.distributed.streamed_part`).
"""

from __future__ import annotations

import hashlib
import io
import os
from collections.abc import Iterator
from dataclasses import dataclass, field

import yaml

from ..errors import SceneError
from ._yaml import (MAX_SCENE_BYTES, _check_document_shape, _Loader, _show, _type_name, _yaml_errors,
                    open_scene_file)

__all__ = ["SceneOutline", "outline", "item_chunks", "CHUNK_ITEMS"]

#: Items handed over at a time by :func:`item_chunks`.
CHUNK_ITEMS = 1 << 16

_COLLECTION_START = (yaml.MappingStartEvent, yaml.SequenceStartEvent)
_COLLECTION_END = (yaml.MappingEndEvent, yaml.SequenceEndEvent)


@dataclass
class SceneOutline:
    """A scene file with its item lists counted, not read (:func:`outline`).

    Attributes
    ----------
    source : str
        The file's path.
    sha256 : str
        SHA-256 (hex) of the file's bytes.
    doc : dict
        The top-level mapping; each item list (a sequence under an item-list key) is replaced by an empty list.
    counts : dict
        Item-list key -> number of items (the keys given as sequences only).
    """

    source: str
    sha256: str
    doc: dict = field(repr=False)
    counts: dict


class _Hashing(io.RawIOBase):
    """A binary file read through a SHA-256, refused beyond ``limit`` bytes (a file that grows while it is read)."""

    def __init__(self, fh, limit: int, source: str):
        self._fh, self._limit, self._source = fh, limit, source
        self.hash, self.count = hashlib.sha256(), 0

    def readable(self) -> bool:
        return True

    def readinto(self, b) -> int:
        k = self._fh.readinto(b)
        if k:
            self.count += k
            if self.count > self._limit:
                raise SceneError(self._source, f"is more than the limit of {self._limit} bytes")
            self.hash.update(memoryview(b)[:k])
        return k


class _ItemLoader(yaml.composer.Composer, _Loader):
    """The scene loader with PyYAML's composer in Python, so that nodes are composed one at a time from libyaml's
    events (the C loader composes a whole document)."""

    def __init__(self, stream):
        _Loader.__init__(self, stream)
        yaml.composer.Composer.__init__(self)
        self.skipped: set = set()

    def one(self):
        """The next node, composed and constructed."""
        try:
            return self.construct_document(self.compose_node(None, None))
        except yaml.composer.ComposerError as e:
            name = str(e.problem or "").rpartition(" ")[2].strip("'\"")
            if name in self.skipped:
                raise SceneError(_source_of(self), f"an alias (*{name}) to an anchor inside an item list, at line "
                                                   f"{e.problem_mark.line + 1}: a reader of the lists in pieces "
                                                   f"(a distributed run) does not keep their items; write the "
                                                   f"value out") from None
            raise

    def skip(self) -> None:
        """Consume the next node's events (its anchors noted: :meth:`one` names them if a later alias needs one)."""
        depth = 0
        while True:
            ev = self.get_event()
            if getattr(ev, "anchor", None) is not None and not isinstance(ev, yaml.AliasEvent):
                self.skipped.add(ev.anchor)
            if isinstance(ev, _COLLECTION_START):
                depth += 1
            elif isinstance(ev, _COLLECTION_END):
                depth -= 1
            if depth == 0:
                return


def _source_of(loader) -> str:
    return getattr(loader, "scene_source", "<scene>")


def _top_level(loader, source: str) -> Iterator:
    """The top-level keys of the document, as they come; the caller consumes each key's value."""
    loader.get_event()  # stream start
    if loader.check_event(yaml.StreamEndEvent):
        raise SceneError(source, "empty scene file")
    loader.get_event()  # document start
    if not loader.check_event(yaml.MappingStartEvent):
        value = loader.one()
        if value is None:
            raise SceneError(source, "empty scene file")
        raise SceneError(source, f"the top level must be a mapping of sections, got {_type_name(value)}")
    loader.get_event()
    seen = set()
    while not loader.check_event(yaml.MappingEndEvent):
        key = loader.one()
        if key == "<<" or not isinstance(key, (str, int, float, bool, type(None))):
            raise SceneError(source, f"a top-level key {_show(key)}: a scene read in pieces needs plain keys")
        if key in seen:
            raise SceneError(source, f"YAML error: duplicate key {_show(key)}")
        seen.add(key)
        yield key
    loader.get_event()


def outline(source, lists) -> SceneOutline:
    """Read a scene file's small sections and count the items of its lists (pass 1 of the module docstring).

    Parameters
    ----------
    source : str or os.PathLike
        The scene file.
    lists : collection of str
        The top-level keys of the item lists (:func:`springsim.scene.yaml_io.load_scene` gives ``particles`` and the
        pair terms' keys); such a key whose value is not a sequence is read as a small section.

    Returns
    -------
    SceneOutline

    Raises
    ------
    SceneError
        As :func:`~springsim.scene.yaml_io.load_scene` for an unreadable file or invalid YAML; also for an alias in
        a small section to an anchor inside an item list, and for a top-level merge key (``<<``), which a reader of
        pieces cannot follow (aliases within and between the lists' items are followed).
    """
    source = os.fspath(source)
    lists = frozenset(lists)
    fh, size = open_scene_file(source)
    with fh, _yaml_errors(source):
        _check_document_shape(io.BufferedReader(_Hashing(fh, MAX_SCENE_BYTES, source)), source, size=size)
        fh.seek(0)
        raw = _Hashing(fh, MAX_SCENE_BYTES, source)
        loader = _ItemLoader(io.BufferedReader(raw))
        loader.scene_source = source
        try:
            doc, counts = {}, {}
            for key in _top_level(loader, source):
                if key in lists and loader.check_event(yaml.SequenceStartEvent):
                    loader.get_event()
                    k = 0
                    while not loader.check_event(yaml.SequenceEndEvent):
                        loader.skip()
                        k += 1
                    loader.get_event()
                    doc[key], counts[key] = [], k
                else:
                    doc[key] = loader.one()
        finally:
            loader.dispose()
        raw.read()  # the rest of the bytes (after the document), for the hash
    return SceneOutline(source=source, sha256=raw.hash.hexdigest(), doc=doc, counts=counts)


def item_chunks(scene: SceneOutline, chunk: int | None = None) -> Iterator[tuple[str, int, list]]:
    """The items of a scene's lists, in document order, a chunk at a time (pass 2 of the module docstring).

    Parameters
    ----------
    scene : SceneOutline
        The file's outline (:func:`outline`).
    chunk : int, optional
        Items per chunk; default :data:`CHUNK_ITEMS` (read at call time).

    Yields
    ------
    key : str
        The list's top-level key (``particles``, ``springs``, ...).
    start : int
        Index of the chunk's first item in its list.
    items : list
        The items, as a whole load constructs them.

    Raises
    ------
    SceneError
        The file changed since :func:`outline` read it (another SHA-256 or item count), or is unreadable.
    """
    source = scene.source
    chunk = CHUNK_ITEMS if chunk is None else int(chunk)
    fh, _ = open_scene_file(source)
    with fh, _yaml_errors(source):
        raw = _Hashing(fh, MAX_SCENE_BYTES, source)
        loader = _ItemLoader(io.BufferedReader(raw))
        loader.scene_source = source
        try:
            for key in _top_level(loader, source):
                if key not in scene.counts or not loader.check_event(yaml.SequenceStartEvent):
                    loader.one()  # a small section (read in the outline), composed for its anchors
                    continue
                loader.get_event()
                start, items = 0, []
                while not loader.check_event(yaml.SequenceEndEvent):
                    items.append(loader.one())
                    if len(items) == chunk:
                        yield key, start, items
                        start, items = start + chunk, []
                if items:
                    yield key, start, items
                if start + len(items) != scene.counts[key]:
                    raise SceneError(source, "changed while it was read (another item count)")
                loader.get_event()
        finally:
            loader.dispose()
        raw.read()
    if raw.hash.hexdigest() != scene.sha256:
        raise SceneError(source, "changed while it was read (another SHA-256)")
