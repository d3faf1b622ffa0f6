"""The YAML layer of the scene reader: the loader, the checks a document passes before it is composed, the limits,
and YAML's errors as one-line :class:`~springsim.errors.SceneError` s.

The loader (:class:`_Loader`) is PyYAML's safe loader (libyaml's C parser where PyYAML has it) with the YAML 1.2
core schema's numbers and duplicate keys refused. :func:`_check_document_shape` refuses a hostile document (deep
nesting, alias bombs) from its event stream, before anything composes it. :mod:`springsim.scene.yaml_io` (whole
documents) and :mod:`springsim.scene.yaml_stream` (documents in pieces) read through them.
"""

from __future__ import annotations

import os
import re
import reprlib
import stat
from contextlib import contextmanager

import yaml

from ..errors import SceneError

#: Largest scene file read [bytes].
MAX_SCENE_BYTES = 256 * 2**20

#: Deepest nesting of collections a scene document may have (scenes need 4; the YAML C parser's
#: composer recurses once per level and would overflow the C stack on deep hostile documents).
MAX_NESTING = 64

#: A document whose aliases would expand it to more than ``max(ALIAS_EXPANSION * bytes,
#: MIN_EXPANDED_NODES)`` nodes is refused (an honest document has fewer nodes than bytes).
ALIAS_EXPANSION = 4
MIN_EXPANDED_NODES = 1_000_000

# libyaml's C parser when PyYAML was built with it (about 10x faster on long lists).
_SafeBase = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _Loader(_SafeBase):
    """``yaml.SafeLoader`` whose numbers follow the YAML 1.2 core schema, and that rejects duplicate keys.

    PyYAML follows YAML 1.1, where an exponent needs a sign and a dot (``1.0e+4``), so ``ke: 1e4``
    would silently be the string ``"1e4"``; a leading zero makes an integer octal (``steps: 010``
    would run 8 steps, ``particle_ids: [000, 010]`` would join particles 0 and 8); and colons make
    base-60 numbers (``steps: 1:30`` would run 90). Here, as in YAML 1.2: ``010`` is the integer 10,
    ``0o10`` is octal, ``0x10`` hexadecimal, ``1e4`` and ``1.0e4`` are floats, and ``1:30`` (or
    ``0b101``) is a string, which every number field refuses with its path named. Underscores
    between digits (``1_000_000``) group digits, as PyYAML has always read them.

    A mapping that gives a key twice (the second would silently win) is an error; keys brought in
    by a merge (``<<: *base``) may be overridden, as YAML specifies.
    """

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
                    continue
                key = self.construct_object(key_node)
                if key in seen:
                    raise yaml.constructor.ConstructorError(None, None, f"duplicate key {_show(key)}",
                                                            key_node.start_mark)
                seen.add(key)
        return super().construct_mapping(node, deep)


_INT_TAG, _FLOAT_TAG = "tag:yaml.org,2002:int", "tag:yaml.org,2002:float"
# YAML 1.2 core: decimal (leading zeros allowed, still decimal), 0o octal, 0x hexadecimal.
_INT_RE = re.compile(r"^(?:[-+]?[0-9][0-9_]*|[-+]?0o[0-7_]+|[-+]?0x[0-9a-fA-F_]+)$")
# YAML 1.2 core: a dot or an exponent (with or without sign), .inf and .nan; no base-60 forms.
_FLOAT_RE = re.compile(r"^(?:[-+]?(?:[0-9][0-9_]*\.[0-9_]*|\.[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)?"
                       r"|[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+"
                       r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$")
# PyYAML's YAML 1.1 number resolvers out, the 1.2 ones in (integers tried first).
_Loader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag not in (_INT_TAG, _FLOAT_TAG)]
    for first, resolvers in _SafeBase.yaml_implicit_resolvers.items()}
_Loader.add_implicit_resolver(_INT_TAG, _INT_RE, list("-+0123456789"))
_Loader.add_implicit_resolver(_FLOAT_TAG, _FLOAT_RE, list("-+0123456789."))


def _construct_int(loader, node):
    """An integer as YAML 1.2 reads it (also for an explicit ``!!int``): ``010`` is ten, ``0o10`` eight."""
    text = loader.construct_scalar(node)
    digits = str(text).replace("_", "")
    sign, body = (-1, digits[1:]) if digits[:1] == "-" else (1, digits.lstrip("+"))
    base = {"0o": 8, "0x": 16}.get(body[:2].lower(), 10)
    try:
        return sign * int(body[2:] if base != 10 else body, base)
    except ValueError:
        raise yaml.constructor.ConstructorError(None, None, f"not an integer: {_show(text)}",
                                                node.start_mark) from None


_Loader.add_constructor(_INT_TAG, _construct_int)



_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxdict, _REPR.maxstring, _REPR.maxlong, _REPR.maxother = 2, 4, 3, 40, 40, 40


def _show(v, limit: int = 60) -> str:
    """A short repr for messages: bounded in time and size for any value (huge, nested, recursive)."""
    s = _REPR.repr(v)
    return s if len(s) <= limit else s[: limit - 3] + "..."


def _type_name(v) -> str:
    return {bool: "a boolean", str: "a string", list: "a list", dict: "a mapping",
            type(None): "null", int: "an integer", float: "a number"}.get(type(v), type(v).__name__)



def _check_document_shape(text, source: str, *, size: int | None = None) -> None:
    """Refuse documents nested deeper than :data:`MAX_NESTING` or whose aliases expand them too far.

    Runs on the parser's event stream (no recursion, memory bounded by the anchors), before
    the document is composed: the composer of the C parser recurses once per nesting level, and
    an alias bomb of a few hundred bytes expands to billions of nodes for anything that walks it.
    ``text`` is the document, or a binary file of ``size`` bytes.
    """
    limit = max(ALIAS_EXPANSION * (len(text) if size is None else size), MIN_EXPANDED_NODES)
    stack: list[list] = []  # open collections: [anchor, expanded size]
    sizes: dict[str, int] = {}
    total = 0
    for ev in yaml.parse(text, Loader=_Loader):
        if isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            if len(stack) >= MAX_NESTING:
                raise SceneError(source, f"YAML document is nested deeper than {MAX_NESTING} levels (line "
                                         f"{ev.start_mark.line + 1})")
            stack.append([ev.anchor, 1])
            continue
        if isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            anchor, size = stack.pop()
        elif isinstance(ev, yaml.ScalarEvent):
            anchor, size = ev.anchor, 1
        elif isinstance(ev, yaml.AliasEvent):
            anchor, size = None, sizes.get(ev.anchor, 1)
        else:
            continue
        if anchor is not None:
            sizes[anchor] = size
        total += size if not stack else 0
        if stack:
            stack[-1][1] += size
            if stack[-1][1] > limit:
                total = stack[-1][1]
        if total > limit:
            raise SceneError(source, f"YAML aliases expand the document to more than {limit} nodes (line "
                                     f"{ev.start_mark.line + 1}); write the repeated items out or use a generator "
                                     f"block")


@contextmanager
def _yaml_errors(source: str):
    """YAML's errors while reading ``source`` as one-line :class:`SceneError` s (with line and column)."""
    try:
        yield
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        what = _one_line(" ".join(x for x in (e.context, e.problem) if x)) or "invalid YAML"
        kind = "YAML error" if isinstance(e, yaml.constructor.ConstructorError) else "YAML syntax error"
        raise SceneError(source, f"{kind}{where}: {what}") from None
    except yaml.YAMLError as e:
        raise SceneError(source, f"YAML error: {_one_line(str(e))}") from None
    except SceneError:
        raise
    except (ValueError, OverflowError) as e:  # e.g. an integer with more digits than Python converts
        raise SceneError(source, f"YAML value out of range: {_one_line(str(e))[:200]}") from None
    except RecursionError:
        raise SceneError(source, "YAML document is nested too deeply") from None
    except OSError as e:  # a file read while it is parsed (springsim.scene.yaml_stream)
        raise SceneError(source, f"cannot read: {e.strerror or e}") from None
    except MemoryError:
        raise SceneError(source, "the scene does not fit in memory") from None


def _one_line(s: str) -> str:
    return " ".join(s.split())


def open_scene_file(source: str):
    """A scene file opened for reading (binary), and its size: a regular file of at most :data:`MAX_SCENE_BYTES`
    (a directory, device, FIFO or socket is refused before it is opened, so that nothing blocks on it)."""
    try:
        st = os.stat(source)
    except FileNotFoundError:
        raise SceneError(source, "no such file") from None
    except OSError as e:
        raise SceneError(source, f"cannot read: {e.strerror or e}") from None
    if stat.S_ISDIR(st.st_mode):
        raise SceneError(source, "is a directory, not a scene file")
    if not stat.S_ISREG(st.st_mode):
        raise SceneError(source, "not a regular file (a device, FIFO or socket); give a scene file")
    if st.st_size > MAX_SCENE_BYTES:
        raise SceneError(source, f"is {st.st_size} bytes, more than the limit of {MAX_SCENE_BYTES} bytes "
                                 f"(springsim.scene.yaml_io.MAX_SCENE_BYTES); use a generator block for big cloths")
    try:
        return open(source, "rb"), st.st_size  # noqa: SIM115 (closed by the caller)
    except OSError as e:
        raise SceneError(source, f"cannot read: {e.strerror or e}") from None
