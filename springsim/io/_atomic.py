"""Output files, written atomically: one helper for trajectories (``.npz``), pictures and mesh exports.

:func:`write_atomic` has a writer fill a temporary file in the target's directory, gives it the
mode of the file it replaces (or ``0o666`` less the umask for a new one, :func:`_new_file_mode`),
fsyncs it and renames it over the target (``os.replace``). On any failure, including
``KeyboardInterrupt``, the temporary file is removed and the target is left as it was, so a file
is never half-written. :func:`check_output_path` checks a target before the work that produces it
(a run, a render): a regular file or nothing, in an existing directory that takes a new file of
that name length, with one of the expected extensions.
"""

from __future__ import annotations

import os
import secrets
import stat
import tempfile
from typing import Callable

from ..errors import SpringsimError

__all__ = ["check_output_path", "save_npz_atomic", "write_atomic"]

_TMP_PREFIX = ".springsim-tmp-"


def _unlink_quietly(path: str) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def _target(path) -> str:
    """The file a write to ``path`` replaces (symbolic links followed), checked to be a regular file or absent."""
    path = os.fspath(path)
    if not path:
        raise SpringsimError("output file name is empty")
    if path.endswith(os.sep) or (os.altsep and path.endswith(os.altsep)):
        raise SpringsimError(f"{path}: names a directory (ends with {os.sep}); give a file name")
    target = os.path.realpath(path)
    if os.path.exists(target):
        mode = os.stat(target).st_mode
        if stat.S_ISDIR(mode):
            raise SpringsimError(f"{path}: is a directory; give a file name")
        if not stat.S_ISREG(mode):
            raise SpringsimError(f"{path}: not a regular file (a device, FIFO or socket); give a file name")
    d = os.path.dirname(target)
    if not os.path.isdir(d):
        raise SpringsimError(f"{path}: directory {d} does not exist")
    return target


def _check_suffix(path: str, suffixes) -> None:
    ext = os.path.splitext(os.path.basename(path))[1]
    if ext.lower() not in suffixes:
        raise SpringsimError(f"{path}: unknown extension {ext or '(none)'!s}; give a file name ending in "
                             f"{' or '.join(suffixes)}")


def _name_max(d: str) -> int | None:
    try:
        n = os.pathconf(d, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):
        return None
    return n if n and n > 0 else None


def check_output_path(path, *, suffixes: tuple[str, ...] | None = None, inputs=()) -> str:
    """Check before the work that produces it that ``path`` can take an atomic write; return the file to write.

    A symbolic link is followed (its target is replaced, the link stays). The target must be a
    regular file or not exist; its directory must exist and accept a new file with a name as long
    as the target's (``PC_NAME_MAX``, then probed by creating and removing a file of that name
    length); with ``suffixes`` (lower case, e.g. ``(".npz",)``), the name must end in one of them; it
    must not be one of the ``inputs`` files (the same file by inode: a link or another spelling).

    Parameters
    ----------
    path : str or PathLike
        The output file.
    suffixes : tuple of str, optional
        Allowed name endings, lower case; default any.
    inputs : iterable of path
        Files the output must not overwrite (the run's input files).

    Returns
    -------
    str
        The file to write: the absolute real path of ``path`` (symbolic links followed).

    Raises
    ------
    SpringsimError
        One line naming the path and the problem.
    """
    name = os.fspath(path)
    target = _target(path)
    if suffixes is not None:
        _check_suffix(name, suffixes)
    for p in inputs:
        try:
            same = os.path.samefile(target, p)
        except (OSError, ValueError, TypeError):
            same = False
        if same:
            raise SpringsimError(f"{name}: is the input file {os.fspath(p)}; give another output name")
    d, base = os.path.split(target)
    length = len(os.fsencode(base))
    limit = _name_max(d)
    if limit is not None and length > limit:
        raise SpringsimError(f"{name}: the file name is {length} bytes long, more than the {limit} bytes "
                             f"{d} allows")
    stem = f".springsim-probe-{secrets.token_hex(4)}-"
    probe = os.path.join(d, stem + "x" * max(length - len(stem), 0))
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as e:
        raise SpringsimError(f"{name}: cannot write in {d}: {e.strerror or e}") from None
    os.close(fd)
    _unlink_quietly(probe)
    return target


def _new_file_mode(existing: str) -> int:
    """Mode for a file replacing ``existing``: its mode if it exists, else 0o666 less the umask."""
    try:
        return stat.S_IMODE(os.stat(existing).st_mode)
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def _fsync_dir(d: str) -> None:
    """Make a rename in ``d`` durable (best effort: not every platform opens directories)."""
    try:
        fd = os.open(d, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_atomic(path, write: Callable[[str], object]) -> str:
    """Write the file ``path`` atomically: ``write(tmp)`` fills the temporary file ``tmp``; return the target.

    ``tmp`` is a new empty file in the target's directory with the target's extension (writers
    that pick the format from the name see the right one). It is then given the mode of the file
    it replaces (or ``0o666`` less the umask), fsync'ed and renamed over the target. A symbolic
    link is followed: its target is replaced, the link kept. On any failure (including
    ``KeyboardInterrupt``) the temporary file is removed and the target is left as it was.

    Raises
    ------
    SpringsimError
        When the target is a directory, device or FIFO, or its directory is missing.
    OSError
        When writing fails (full disk, permissions); the target is unchanged.
    """
    target = _target(path)
    d = os.path.dirname(target)
    mode = _new_file_mode(target)
    fd, tmp = tempfile.mkstemp(prefix=_TMP_PREFIX, suffix=os.path.splitext(target)[1], dir=d)
    try:
        try:
            write(tmp)
            os.fchmod(fd, mode)
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, target)
    except BaseException:
        _unlink_quietly(tmp)
        raise
    _fsync_dir(d)
    return target


def save_npz_atomic(path, **arrays) -> None:
    """Write ``arrays`` to the ``.npz`` file ``path`` atomically (:func:`write_atomic` around ``np.savez``).

    Parameters
    ----------
    path : str or PathLike
        Target file, used exactly as given (no ``.npz`` is appended); it must be a regular
        file or not exist (:func:`check_output_path`).
    **arrays : ndarray
        Named arrays, as for ``np.savez``.

    Raises
    ------
    SpringsimError
        When the target is not a regular file or its directory is missing.
    OSError
        When writing fails (full disk, permissions); the target is unchanged.
    """
    import numpy as np

    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    write_atomic(path, write)
