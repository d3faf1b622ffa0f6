"""Canonical generated scenes shared by tests, benchmarks and the YAML generator block.

:func:`cloth_grid_pairs` is the vectorised grid topology; :func:`add_cloth_grid` adds a
cloth to a builder; :func:`benchmark_cloth` is *the* benchmark cloth of the solver
and accuracy issues (1 m square, 1 kg, edge y = 0 pinned, h = 1/60 s).
"""

from __future__ import annotations

import numpy as np

from ..errors import SceneError

__all__ = ["cloth_grid_pairs", "cloth_pin_mask", "add_cloth_grid", "benchmark_cloth",
           "BENCHMARK_DT", "PIN_MODES"]

#: Time step of the benchmark cloth [s].
BENCHMARK_DT = 1.0 / 60.0

#: Accepted values of ``pin``.
PIN_MODES = ("none", "edge", "corners", "ends")


def cloth_grid_pairs(nx: int, ny: int, *, bending: bool = True) -> dict[str, np.ndarray]:
    """Spring index pairs of an ``nx`` x ``ny`` grid, particle ``(i, j)`` at index ``j*nx + i``.

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
        raise SceneError("pin", f"must be one of {', '.join(PIN_MODES)}, got {pin!r}")
    return mask.ravel()


def add_cloth_grid(builder, nx: int, ny: int, *, origin=(0.0, 0.0, 0.0), spacing: float | None = None,
                   size: tuple[float, float] | None = None, plane: str = "xy",
                   mass: float | None = None, total_mass: float | None = None, drag: float = 0.0,
                   ke: float = 1e4, kd: float = 0.0, ke_y: float | None = None, kd_y: float | None = None,
                   ke_shear: float | None = None, kd_shear: float | None = None,
                   bending: bool = True, ke_bend: float = 1e2, kd_bend: float = 0.0,
                   pin: str = "edge") -> range:
    """Add an ``nx`` x ``ny`` cloth of particles and springs to ``builder``.

    Parameters
    ----------
    nx, ny
        Particles along the first and second in-plane axis (each >= 2).
    origin
        Position of particle (0, 0) [m].
    spacing, size
        Grid spacing [m], or the cloth's extent (sx, sy) [m]; default size (1, 1).
    plane
        Two axes spanned by the grid: ``"xy"``, ``"xz"`` or ``"yz"``.
    mass, total_mass
        Mass of each particle [kg], or of the whole cloth shared equally; default 1 kg in total.
    drag
        Linear drag per particle [N s/m].
    ke, kd
        Structural springs along i (and along j unless ``ke_y``/``kd_y`` are given) [N/m], [N s/m].
    ke_y, kd_y
        Structural springs along j; default ``ke``, ``kd``.
    ke_shear, kd_shear
        Diagonal springs; default ``ke``, ``kd``.
    bending, ke_bend, kd_bend
        Whether to add distance-two springs along i and j, and their stiffness and damping.
    pin
        One of :data:`PIN_MODES`.

    Returns
    -------
    range
        Indices of the new particles; particle ``(i, j)`` is ``start + j*nx + i``.
    """
    if int(nx) != nx or int(ny) != ny or nx < 2 or ny < 2:
        raise SceneError("cloth.n", f"needs at least 2x2 particles, got {nx}x{ny}")
    nx, ny = int(nx), int(ny)
    axes = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}
    if plane not in axes:
        raise SceneError("cloth.plane", f"must be one of {', '.join(axes)}, got {plane!r}")
    if spacing is not None and size is not None:
        raise SceneError("cloth", "give spacing or size, not both")
    if spacing is not None:
        dx = dy = float(spacing)
    else:
        sx, sy = (1.0, 1.0) if size is None else size
        dx, dy = float(sx) / (nx - 1), float(sy) / (ny - 1)
    if not (dx > 0 and dy > 0 and np.isfinite(dx) and np.isfinite(dy)):
        raise SceneError("cloth.spacing", f"must be > 0, got {dx:g}, {dy:g}")
    if mass is not None and total_mass is not None:
        raise SceneError("cloth", "give mass or total_mass, not both")
    m = (1.0 if total_mass is None else float(total_mass)) / (nx * ny) if mass is None else float(mass)

    ii, jj = np.meshgrid(np.arange(nx, dtype=np.float64), np.arange(ny, dtype=np.float64))
    pos = np.tile(np.asarray(origin, dtype=np.float64), (nx * ny, 1))
    a, b = axes[plane]
    pos[:, a] += ii.ravel() * dx
    pos[:, b] += jj.ravel() * dy
    particles = builder.add_particles(pos, None, m, drag=drag, fixed=cloth_pin_mask(nx, ny, pin))
    off = particles.start

    topo = cloth_grid_pairs(nx, ny, bending=bending)
    builder.add_springs(topo["structural_x"] + off, ke, kd)
    builder.add_springs(topo["structural_y"] + off, ke if ke_y is None else ke_y, kd if kd_y is None else kd_y)
    builder.add_springs(topo["shear"] + off, ke if ke_shear is None else ke_shear,
                        kd if kd_shear is None else kd_shear)
    if bending:
        builder.add_springs(topo["bending"] + off, ke_bend, kd_bend)
    return particles


def benchmark_cloth(n: int, *, kd: float = 0.0, ke: float = 1e4, ke_bend: float = 1e2,
                    ke_shear: float | None = None, total_mass: float = 1.0, pin: str = "edge"):
    """The benchmark cloth: a 1 m square of ``n`` x ``n`` particles in z = 0, falling under gravity.

    Total mass 1 kg shared equally; structural and shear springs ``ke`` = 1e4 N/m,
    bending (distance two) springs ``ke_bend`` = 1e2 N/m, all with damping ``kd``
    (default 0); gravity -9.81 m/s^2 along z; the edge y = 0 pinned. Use it with
    ``h = BENCHMARK_DT`` (1/60 s), starting at rest.

    Returns
    -------
    Model
    """
    from ..builder import ModelBuilder

    b = ModelBuilder(gravity=-9.81, up_axis="z")
    add_cloth_grid(b, n, n, size=(1.0, 1.0), total_mass=total_mass, ke=ke, kd=kd,
                   ke_shear=ke if ke_shear is None else ke_shear, kd_shear=kd,
                   bending=True, ke_bend=ke_bend, kd_bend=kd, pin=pin)
    b.metadata.update(name=f"benchmark_cloth_{n}", cloth_shape=(n, n))
    return b.finalize()
