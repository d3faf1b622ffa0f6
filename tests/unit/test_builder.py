"""ModelBuilder: index ranges, gravity/up axis, and the cloth grid generator."""

import numpy as np
import pytest

from springsim import ModelBuilder, SceneError
from springsim.model.topology import PIN_MODES, cloth_grid_pairs, cloth_pin_mask


def test_index_ranges_and_counts():
    """Single adds return indices and bulk adds return ranges continuing the numbering."""
    b = ModelBuilder()
    assert b.add_particle((0, 0, 0), mass=1.0) == 0
    r = b.add_particles(np.zeros((3, 3)) + [[1, 0, 0]], mass=[1, 2, 3])
    assert r == range(1, 4) and b.particle_count == 4
    assert b.add_springs([[0, 1], [1, 2]], ke=[1, 2]) == range(0, 2)
    assert b.add_spring(2, 3, ke=5.0) == 2 and b.spring_count == 3
    assert b.add_gravitational(0, 3, G=1.0) == 0 and b.gravitational_count == 1


@pytest.mark.parametrize("up, index", [("x", 0), ("y", 1), ("z", 2), (1, 1)])
def test_up_axis_and_gravity(up, index):
    """The up axis (name or index) and gravity magnitude reach the model."""
    b = ModelBuilder(gravity=-3.0, up_axis=up)
    b.add_particle((0, 0, 0), mass=1.0)
    m = b.finalize()
    assert m.up_axis == index and m.gravity == -3.0


def test_bad_up_axis():
    """An unknown up axis is a SceneError naming up_axis."""
    b = ModelBuilder(up_axis="w")
    b.add_particle((0, 0, 0), mass=1.0)
    with pytest.raises(SceneError, match="up_axis"):
        b.finalize()


@pytest.mark.parametrize("pin", PIN_MODES)
def test_cloth_grid_counts_and_pins(pin):
    """add_cloth_grid adds nx*ny particles, the gallery topology, and the requested pins."""
    nx, ny = 5, 4
    b = ModelBuilder()
    b.add_particle((9, 9, 9), mass=1.0)
    r = b.add_cloth_grid(nx, ny, size=(2.0, 3.0), total_mass=2.0, pin=pin)
    m = b.finalize()
    assert r == range(1, 1 + nx * ny)
    topo = cloth_grid_pairs(nx, ny, bending=True)
    assert m.spring_count == sum(len(v) for v in topo.values())
    assert m.spring_indices.min() == 1
    np.testing.assert_array_equal(m.particle_fixed[1:], cloth_pin_mask(nx, ny, pin))
    np.testing.assert_allclose(m.particle_mass[1:].sum(), 2.0)
    np.testing.assert_allclose(m.particle_q[1:].max(axis=0), [2.0, 3.0, 0.0])
    # rest lengths are the initial distances: structural along x = 2/(nx-1)
    np.testing.assert_allclose(m.spring_rest_length[: nx * ny - ny][:1], 2.0 / (nx - 1))


def test_cloth_grid_planes_and_spacing():
    """``plane`` chooses the spanned axes; ``spacing`` sets the grid step from ``origin``."""
    for plane, axes in (("xy", (0, 1)), ("xz", (0, 2)), ("yz", (1, 2))):
        b = ModelBuilder()
        b.add_cloth_grid(3, 2, origin=(1, 2, 3), spacing=0.5, plane=plane, mass=0.1, pin="none")
        q = b.finalize().particle_q
        ext = q.max(axis=0) - q.min(axis=0)
        expected = np.zeros(3)
        expected[axes[0]], expected[axes[1]] = 1.0, 0.5
        np.testing.assert_allclose(ext, expected)
        np.testing.assert_allclose(q[0], [1, 2, 3])


def test_cloth_grid_stiffness_families():
    """Structural (x, y), shear and bending springs get their own stiffness and damping."""
    b = ModelBuilder()
    b.add_cloth_grid(4, 4, ke=1.0, kd=0.1, ke_y=2.0, kd_y=0.2, ke_shear=3.0, kd_shear=0.3,
                     ke_bend=4.0, kd_bend=0.4, pin="none")
    m = b.finalize()
    topo = cloth_grid_pairs(4, 4)
    counts = [len(topo[k]) for k in ("structural_x", "structural_y", "shear", "bending")]
    np.testing.assert_array_equal(m.spring_stiffness, np.repeat([1.0, 2.0, 3.0, 4.0], counts))
    np.testing.assert_array_equal(m.spring_damping, np.repeat([0.1, 0.2, 0.3, 0.4], counts))


@pytest.mark.parametrize("kwargs, fragment", [
    (dict(nx=1, ny=3), "cloth.n"),
    (dict(nx=3, ny=3, plane="xx"), "cloth.plane"),
    (dict(nx=3, ny=3, spacing=0.1, size=(1, 1)), "spacing or size"),
    (dict(nx=3, ny=3, mass=1.0, total_mass=1.0), "mass or total_mass"),
    (dict(nx=3, ny=3, spacing=-1.0), "cloth.spacing"),
    (dict(nx=3, ny=3, pin="topp"), "cloth.pin: unknown pin name 'topp'; choose one of none, edge, corners"),
    (dict(nx=3, ny=3, ke="1e4"), "cloth.ke: must be a number"),
    (dict(nx=3, ny=3, ke=-1.0), "cloth.ke: must be >= 0"),
    (dict(nx=3, ny=3, origin=(0, 0)), "cloth.origin"),
    (dict(nx=3, ny=3, size=(1.0, 0.0)), r"cloth.size\[1\]: must be > 0"),
    (dict(nx=3.0, ny=3), "cloth.nx: must be an integer"),
    (dict(nx=3, ny=3, bending="yes"), "cloth.bending"),
    (dict(nx=3, ny=3, total_mass=True), "cloth.total_mass: must be a number"),
])
def test_cloth_grid_errors(kwargs, fragment):
    """Invalid generator parameters raise SceneError naming the parameter."""
    b = ModelBuilder()
    with pytest.raises(SceneError, match=fragment):
        b.add_cloth_grid(**kwargs)


def test_bulk_arrays_keep_item_paths():
    """A bad value deep in a bulk array is reported with its global item index."""
    rng = np.random.default_rng(20261122)
    b = ModelBuilder()
    b.add_particles(rng.normal(size=(10, 3)), mass=1.0)
    ke = np.abs(rng.normal(size=9))
    ke[6] = -1.0
    b.add_springs(np.stack([np.arange(9), np.arange(1, 10)], axis=1), ke)
    with pytest.raises(SceneError, match=r"springs\[6\]\.stiffness: must be >= 0"):
        b.finalize()
