"""Frames streamed to a trajectory file as they are recorded, so that no process holds them all.

:class:`FrameSpool` appends each frame's positions and velocities to two temporary files next to the target (hidden
names, as :func:`~springsim.io._atomic.write_atomic` uses); :meth:`FrameSpool.finish` then writes the trajectory
``.npz`` (the layout of :meth:`springsim.run.driver.Trajectory.save`: ``t``, ``q``, ``qd``, ``meta``) atomically,
copying the spooled frames into it in chunks of a few MB, and removes the temporary files. Until then the target is
untouched (a failure while finishing leaves it as it was, and the frames spooled, e.g. for a rescue file);
:meth:`FrameSpool.discard` removes the temporary files. Memory: one frame at a time, whatever the frame count.
"""

from __future__ import annotations

import json
import os
import tempfile
import zipfile

import numpy as np

from ._atomic import _TMP_PREFIX, _target, _unlink_quietly, write_atomic

__all__ = ["FrameSpool"]

_CHUNK = 1 << 24  # bytes copied at a time


class FrameSpool:
    """A trajectory file written frame by frame (module docstring).

    Parameters
    ----------
    path : str or PathLike
        The target ``.npz`` (a regular file or nothing, in an existing directory); written by :meth:`finish` only.
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        target = _target(path)
        d = os.path.dirname(target)
        self.count = 0
        self.particles = None
        self._files = []
        try:
            for _ in range(2):
                fd, name = tempfile.mkstemp(prefix=_TMP_PREFIX, suffix=".frames", dir=d)
                self._files.append((os.fdopen(fd, "wb"), name))
        except BaseException:
            self.discard()
            raise

    def append(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Append one frame.

        Parameters
        ----------
        q, qd : ndarray, shape (N, 3)
            Positions [m] and velocities [m/s] of every particle.
        """
        q = np.ascontiguousarray(q, dtype="<f8")
        if self.particles is None:
            self.particles = q.shape[0]
        if q.shape != (self.particles, 3) or np.shape(qd) != q.shape:
            raise ValueError(f"a frame must have shape ({self.particles}, 3), got {q.shape} and {np.shape(qd)}")
        for (fh, _), a in zip(self._files, (q, np.ascontiguousarray(qd, dtype="<f8"))):
            fh.write(memoryview(a).cast("B"))
        self.count += 1

    def finish(self, t, meta: dict, path=None) -> str:
        """Write the trajectory file atomically from the frames so far (they stay spooled: :meth:`discard` them).

        Parameters
        ----------
        t : array_like, shape (count,)
            The frames' times [s].
        meta : dict
            The trajectory's ``meta`` (JSON-serialisable; ``format`` and ``format_version`` included by the caller).
        path : str or PathLike, optional
            Where to write it (a rescue file); default the spool's target.

        Returns
        -------
        str
            The file written (symbolic links followed).

        Raises
        ------
        ValueError
            ``t`` does not have one time per frame.
        OSError
            Writing failed; the target is unchanged.
        """
        t = np.asarray(t, dtype=np.float64)
        if t.shape != (self.count,):
            raise ValueError(f"t must have one time per frame ({self.count}), got shape {t.shape}")
        shape = (self.count, self.particles or 0, 3)
        for fh, _ in self._files:
            fh.flush()

        def write(tmp):
            with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
                with zf.open("t.npy", "w", force_zip64=True) as f:
                    np.lib.format.write_array(f, t, allow_pickle=False)
                for name, (_, spool) in zip(("q", "qd"), self._files):
                    with zf.open(f"{name}.npy", "w", force_zip64=True) as f:
                        np.lib.format.write_array_header_1_0(
                            f, {"descr": "<f8", "fortran_order": False, "shape": shape})
                        with open(spool, "rb") as src:
                            while True:
                                chunk = src.read(_CHUNK)
                                if not chunk:
                                    break
                                f.write(chunk)
                with zf.open("meta.npy", "w", force_zip64=True) as f:
                    np.lib.format.write_array(f, np.array(json.dumps(meta, sort_keys=True)), allow_pickle=False)

        if not self._files:
            raise ValueError("the spool was discarded")
        return write_atomic(self.path if path is None else path, write)

    def discard(self) -> None:
        """Remove the temporary files (the target is untouched); the spool takes no more frames."""
        for fh, name in self._files:
            try:
                fh.close()
            except OSError:
                pass
            _unlink_quietly(name)
        self._files = []
