"""Scenes of the distributed tests (importable by the test processes and by the MPI scripts)."""

from __future__ import annotations

import numpy as np

from springsim import ModelBuilder
from springsim.forces._data import data_terms
from springsim.scene import benchmark_cloth


def irregular(seed: int = 3):
    """40 particles scattered in a 1 m cube: 4 fixed spread over the index range (so over several ranks), random
    springs (many crossing any contiguous partition), gravitational pairs, drag on some particles, damping."""
    rng = np.random.default_rng(seed)
    b = ModelBuilder()
    n = 40
    pos = rng.random((n, 3))
    vel = 0.2 * rng.standard_normal((n, 3))
    for k in range(n):
        b.add_particle(pos[k], vel[k], mass=0.05 + 0.1 * rng.random(), drag=0.02 if k % 5 == 0 else 0.0)
    b.set_fixed([0, 13, 27, 39])
    pairs = set()
    while len(pairs) < 110:
        i, j = (int(x) for x in rng.integers(0, n, 2))
        if i != j and (j, i) not in pairs:
            pairs.add((i, j))
    for i, j in sorted(pairs):
        rest = float(np.linalg.norm(pos[i] - pos[j])) * (0.9 + 0.2 * rng.random())
        b.add_spring(i, j, stiffness=50.0 + 200.0 * rng.random(), damping=0.05, rest_length=rest)
    for _ in range(25):
        i, j = (int(x) for x in rng.integers(0, n, 2))
        if i != j:
            b.add_gravitational(i, j, G=5e-3, softening=0.05)
    return b.finalize()


def shuffled_cloth(n: int = 12, seed: int = 5):
    """The benchmark cloth with its particles numbered at random: contiguous blocks of that numbering are
    scattered over the cloth, a graph partition's parts are not."""
    import dataclasses

    m = benchmark_cloth(n)
    perm = np.random.default_rng(seed).permutation(m.particle_count)  # new index k holds old particle perm[k]
    new_of_old = np.argsort(perm)
    kw = {f.name: getattr(m, f.name)[perm] for f in dataclasses.fields(m) if f.name.startswith("particle_")}
    terms = {name: dict(data) for name, data in m.terms.items()}
    for name, cls in data_terms():  # per-particle arrays follow their particles, pair lists are renumbered
        for spec in cls.data:
            if spec.per == "particle":
                terms[name][spec.name] = terms[name][spec.name][perm]
        if "indices" in terms[name]:
            terms[name]["indices"] = new_of_old[terms[name]["indices"]]
    return dataclasses.replace(m, **kw, terms=terms, cloth_grids=())


def scene(name: str):
    if name == "cloth":
        return benchmark_cloth(8)
    if name == "cloth32":  # big enough for a multi-level GAMG hierarchy
        return benchmark_cloth(32)
    if name == "shuffled_cloth":
        return shuffled_cloth()
    if name == "irregular":
        return irregular()
    raise ValueError(name)
