"""Canonical generated scenes shared by tests, benchmarks and the YAML ``benchmark_cloth`` block.

:func:`benchmark_cloth` is *the* benchmark cloth of the solver and accuracy benchmarks
(1 m square, 1 kg, edge y = 0 pinned, h = 1/60 s).
"""

from __future__ import annotations

from ..model.builder import ModelBuilder, unalias

__all__ = ["benchmark_cloth", "benchmark_cloth_grid", "accuracy_cloth", "BENCHMARK_DT"]

#: Time step of the benchmark cloth [s].
BENCHMARK_DT = 1.0 / 60.0


def benchmark_cloth_grid(n: int, *, stiffness: float | None = None, damping: float | None = None,
                         stiffness_shear: float | None = None, stiffness_bend: float | None = None,
                         total_mass: float = 1.0, pin="edge", ke: float | None = None, kd: float | None = None,
                         ke_shear: float | None = None, ke_bend: float | None = None) -> dict:
    """Keyword arguments of :meth:`springsim.ModelBuilder.add_cloth_grid` for the benchmark cloth of ``n`` x ``n``.

    The single definition of the benchmark cloth, used by :func:`benchmark_cloth` and the YAML
    ``benchmark_cloth:`` block: a 1 m square of total mass ``total_mass`` [kg]; structural and shear
    springs ``stiffness`` [N/m] (default 1e4; shear ``stiffness_shear`` if given), bending springs
    ``stiffness_bend`` (default 100), all with damping ``damping`` [N s/m] (default 0); ``pin`` as for
    the grid. ``ke``, ``kd``, ``ke_shear``, ``ke_bend`` are aliases
    (:data:`springsim.model.builder.COEFFICIENT_ALIASES`).

    Parameters
    ----------
    n : int
        Particles per side.
    stiffness, stiffness_shear, stiffness_bend : float, optional
        Spring stiffnesses [N/m] of the structural, shear and bending springs.
    damping : float, optional
        Damping [N s/m] of every spring.
    total_mass : float
        Mass of the cloth [kg].
    pin : str or array_like
        Fixed particles, as for :meth:`springsim.ModelBuilder.add_cloth_grid`.
    ke, kd, ke_shear, ke_bend : float, optional
        Aliases of ``stiffness``, ``damping``, ``stiffness_shear``, ``stiffness_bend``.

    Returns
    -------
    dict
        Keyword arguments of :meth:`springsim.ModelBuilder.add_cloth_grid`.

    Raises
    ------
    SceneError
        A coefficient given under both its name and its alias.
    """
    c = unalias("benchmark_cloth", {"stiffness": stiffness, "ke": ke, "damping": damping, "kd": kd,
                                    "stiffness_shear": stiffness_shear, "ke_shear": ke_shear,
                                    "stiffness_bend": stiffness_bend, "ke_bend": ke_bend})
    k = {name: v for name, (v, _) in c.items()}
    ke_ = 1e4 if k["stiffness"] is None else k["stiffness"]
    kd_ = 0.0 if k["damping"] is None else k["damping"]
    return {"nx": n, "ny": n, "size": (1.0, 1.0), "total_mass": total_mass, "stiffness": ke_, "damping": kd_,
            "stiffness_shear": ke_ if k["stiffness_shear"] is None else k["stiffness_shear"], "damping_shear": kd_,
            "bending": True, "stiffness_bend": 1e2 if k["stiffness_bend"] is None else k["stiffness_bend"],
            "damping_bend": kd_, "pin": pin}


def benchmark_cloth(n: int, **options):
    """The benchmark cloth: a 1 m square of ``n`` x ``n`` particles in z = 0, falling under gravity.

    Total mass 1 kg shared equally; structural and shear springs 1e4 N/m, bending (distance
    two) springs 1e2 N/m, undamped; gravity -9.81 m/s^2 along z; the edge y = 0 pinned. Use it
    with ``h = BENCHMARK_DT`` (1/60 s), starting at rest. ``options`` (``stiffness``, ``damping``,
    ``stiffness_shear``, ``stiffness_bend``, their aliases ``ke``, ``kd``, ``ke_shear``, ``ke_bend``,
    ``total_mass``, ``pin``) change it, see :func:`benchmark_cloth_grid`; they are
    validated by :meth:`springsim.ModelBuilder.add_cloth_grid`.

    Parameters
    ----------
    n : int
        Particles per side.
    **options
        Keyword arguments of :func:`benchmark_cloth_grid`.

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

    Parameters
    ----------
    n : int
        Particles per side.

    Returns
    -------
    Model
    """
    return benchmark_cloth(n, stiffness=1e3, stiffness_shear=1e3, stiffness_bend=1e2)
