"""Cloth-grid topology: vectorised spring index pairs and pin masks of an ``nx`` x ``ny`` grid.

Particle ``(i, j)`` of a grid has the local index ``j*nx + i``; ``i`` runs along the first
in-plane axis, ``j`` along the second. Pure functions of the grid shape, shared by
:meth:`springsim.ModelBuilder.add_cloth_grid` and the exporters.
"""

from __future__ import annotations

import numpy as np

from .errors import SceneError

__all__ = ["cloth_grid_pairs", "cloth_pin_mask", "cloth_quads", "PIN_MODES", "PLANES"]

#: Accepted values of ``pin``.
PIN_MODES = ("none", "edge", "corners", "ends")

#: Accepted values of ``plane`` and the axes they span.
PLANES = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}


def cloth_grid_pairs(nx: int, ny: int, *, bending: bool = True) -> dict[str, np.ndarray]:
    """Spring index pairs of an ``nx`` x ``ny`` grid (local indices ``j*nx + i``).

    Returns a dict with ``structural_x`` (along i), ``structural_y`` (along j),
    ``shear`` (both diagonals) and, when ``bending``, ``bending`` (distance two along
    i and j); each an int64 array of shape (k, 2).
    """
    idx = np.arange(nx * ny, dtype=np.int64).reshape(ny, nx)

    def pairs(a, b):
        return np.stack([a.ravel(), b.ravel()], axis=1)

    out = {
        "structural_x": pairs(idx[:, :-1], idx[:, 1:]),
        "structural_y": pairs(idx[:-1, :], idx[1:, :]),
        "shear": np.concatenate([pairs(idx[:-1, :-1], idx[1:, 1:]), pairs(idx[:-1, 1:], idx[1:, :-1])]),
    }
    if bending:
        out["bending"] = np.concatenate([pairs(idx[:, :-2], idx[:, 2:]), pairs(idx[:-2, :], idx[2:, :])])
    return out


def cloth_pin_mask(nx: int, ny: int, pin: str) -> np.ndarray:
    """Boolean mask (nx*ny,) of pinned particles.

    ``"edge"``: the row j = 0; ``"corners"``: its two corners; ``"ends"``: rows
    j = 0 and j = ny - 1; ``"none"``: nothing.
    """
    mask = np.zeros((ny, nx), dtype=bool)
    if pin == "edge":
        mask[0, :] = True
    elif pin == "corners":
        mask[0, 0] = mask[0, -1] = True
    elif pin == "ends":
        mask[0, :] = mask[-1, :] = True
    elif pin != "none":
        raise SceneError("cloth.pin", f"must be one of {', '.join(PIN_MODES)}, got {pin!r:.60}")
    return mask.ravel()


def cloth_quads(start: int, nx: int, ny: int) -> np.ndarray:
    """The (nx-1)(ny-1) quads (Q, 4) of a grid whose particle (0, 0) has index ``start``, counter-clockwise."""
    idx = start + np.arange(nx * ny, dtype=np.int64).reshape(ny, nx)
    return np.stack([idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()], axis=1)
