"""Canonical generated scenes shared by tests, benchmarks and the YAML ``benchmark_cloth`` block.

:func:`benchmark_cloth` is *the* benchmark cloth of the solver and accuracy benchmarks
(1 m square, 1 kg, edge y = 0 pinned, h = 1/60 s).
"""

from __future__ import annotations

from ..builder import ModelBuilder

__all__ = ["benchmark_cloth", "benchmark_cloth_grid", "accuracy_cloth", "BENCHMARK_DT"]

#: Time step of the benchmark cloth [s].
BENCHMARK_DT = 1.0 / 60.0


def benchmark_cloth_grid(n: int, *, kd: float = 0.0, ke: float = 1e4, ke_bend: float = 1e2,
                         ke_shear: float | None = None, total_mass: float = 1.0, pin: str = "edge") -> dict:
    """Keyword arguments of :meth:`springsim.ModelBuilder.add_cloth_grid` for the benchmark cloth of ``n`` x ``n``.

    The single definition of the benchmark cloth, used by :func:`benchmark_cloth` and the YAML
    ``benchmark_cloth:`` block: a 1 m square of total mass ``total_mass`` [kg]; structural and shear
    springs ``ke`` [N/m] (shear ``ke_shear`` if given), bending springs ``ke_bend``, all with damping
    ``kd`` [N s/m]; ``pin`` as for the grid.
    """
    return dict(nx=n, ny=n, size=(1.0, 1.0), total_mass=total_mass, ke=ke, kd=kd,
                ke_shear=ke if ke_shear is None else ke_shear, kd_shear=kd, bending=True, ke_bend=ke_bend,
                kd_bend=kd, pin=pin)


def benchmark_cloth(n: int, **options):
    """The benchmark cloth: a 1 m square of ``n`` x ``n`` particles in z = 0, falling under gravity.

    Total mass 1 kg shared equally; structural and shear springs 1e4 N/m, bending (distance
    two) springs 1e2 N/m, undamped; gravity -9.81 m/s^2 along z; the edge y = 0 pinned. Use it
    with ``h = BENCHMARK_DT`` (1/60 s), starting at rest. ``options`` (``kd``, ``ke``, ``ke_bend``,
    ``ke_shear``, ``total_mass``, ``pin``) change it, see :func:`benchmark_cloth_grid`; they are
    validated by :meth:`springsim.ModelBuilder.add_cloth_grid`.

    Returns
    -------
    Model
    """
    b = ModelBuilder(gravity=-9.81, up_axis="z")
    b.add_cloth_grid(**benchmark_cloth_grid(n, **options))
    b.metadata.update(name=f"benchmark_cloth_{n}")
    return b.finalize()


def accuracy_cloth(n: int):
    """The accuracy benchmarks' cloth: the benchmark cloth with structural and shear springs of 1e3 N/m.

    Softer than :func:`benchmark_cloth` (bending springs 1e2 N/m as there), so that its fall from
    rest buckles within a second: the motion whose error the accuracy and frame-cost benchmarks
    measure at animation time steps.
    """
    return benchmark_cloth(n, ke=1e3, ke_shear=1e3, ke_bend=1e2)
