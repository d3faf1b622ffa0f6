"""Scene loader: the Nemo format, generator blocks, solver options and every validation error."""

import numpy as np
import pytest

from springsim import ModelBuilder, SceneError
from springsim.model.topology import cloth_grid_pairs
from springsim.scene import PlotSpec, SolverConfig, load_scene, parse_scene

HEAD = "solver: {type: implicit_euler, timestep: 0.01}\n"
TWO = HEAD + "particles:\n  - {pos: [0, 0, 1], mass: 1, fixed: true}\n  - {pos: [0, 0, 0], mass: 2}\n"


def _err(text: str) -> str:
    with pytest.raises(SceneError) as info:
        load_scene(text)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


def test_minimal_scene_defaults():
    """A two-particle scene loads with the documented defaults (gravity -9.81 along z, zero velocity)."""
    s = load_scene(TWO + "springs:\n  - {particle_ids: [0, 1], stiffness: 100}\n")
    m = s.model
    assert m.particle_count == 2 and m.spring_count == 1
    assert m.gravity == -9.81 and m.up_axis == 2
    np.testing.assert_array_equal(m.particle_qd, 0.0)
    np.testing.assert_array_equal(m.particle_fixed, [True, False])
    assert m.spring_rest_length[0] == pytest.approx(1.0)
    assert m.spring_damping[0] == 0.0
    assert s.config == SolverConfig(integrator="implicit_euler", dt=0.01)
    assert s.plot is None and s.source == "<string>"


def test_all_fields_are_read():
    """Every per-item field of particles, springs, gravitational and plot reaches the model."""
    text = """
solver: {type: midpoint, timestep: 0.005, gravity: -3.5, up_axis: y, steps: 7}
particles:
  - {pos: [0, 1, 2], vel: [3, 4, 5], mass: 0.5, drag: 0.25, radius: 0.1}
  - {pos: [1, 1, 2], mass: 1.5, fixed: false}
springs:
  - {particle_ids: [0, 1], stiffness: 10.0, damping: 0.5, rest_length: 0.75}
gravitational:
  - {particle_ids: [1, 0], G: 6.5}
plot: {particle_id: 1, dof: 2, y_range: [-1, 1.5]}
"""
    s = load_scene(text)
    m = s.model
    np.testing.assert_array_equal(m.particle_q, [[0, 1, 2], [1, 1, 2]])
    np.testing.assert_array_equal(m.particle_qd, [[3, 4, 5], [0, 0, 0]])
    np.testing.assert_array_equal(m.particle_mass, [0.5, 1.5])
    np.testing.assert_array_equal(m.particle_drag, [0.25, 0.0])
    assert m.particle_radius[0] == 0.1 and np.isnan(m.particle_radius[1])
    assert (m.spring_stiffness[0], m.spring_damping[0], m.spring_rest_length[0]) == (10.0, 0.5, 0.75)
    np.testing.assert_array_equal(m.gravitational_indices, [[1, 0]])
    assert m.gravitational_G[0] == 6.5
    assert m.gravity == -3.5 and m.up_axis == 1
    assert s.config.steps == 7 and s.config.integrator == "midpoint"
    assert s.plot == PlotSpec(particle_id=1, dof=2, y_range=(-1.0, 1.5))


def test_anchors_and_aliases():
    """YAML anchors and aliases (as in generated Nemo files) resolve to shared values."""
    text = HEAD + """
particles:
  - {pos: &p0 [0, 0, 0], vel: &v0 [1, 0, 0], mass: &m 0.3}
  - {pos: [0, 0, 1], vel: *v0, mass: *m}
springs:
  - &s {particle_ids: [0, 1], stiffness: 50}
x-defaults: &d {stiffness: 7}
"""
    m = load_scene(text).model
    np.testing.assert_array_equal(m.particle_qd, [[1, 0, 0], [1, 0, 0]])
    np.testing.assert_array_equal(m.particle_mass, [0.3, 0.3])


def test_exponent_floats_without_sign():
    """``1e4`` and ``1.0e4`` are numbers (YAML 1.2), while a quoted '1e4' stays a string and is rejected."""
    s = load_scene(TWO + "springs:\n  - {particle_ids: [0, 1], stiffness: 1.0e4, damping: 2e-1}\n")
    assert s.model.spring_stiffness[0] == 1e4 and s.model.spring_damping[0] == 0.2
    assert "must be a number" in _err(TWO + "springs:\n  - {particle_ids: [0, 1], stiffness: '1e4'}\n")


def test_integers_follow_yaml_1_2():
    """Leading zeros are decimal (``010`` is 10, not octal 8), ``0o``/``0x`` prefix octal/hex, and ``1:30`` is no number."""
    nine = HEAD.replace("}", ", steps: 010}") + "particles:\n" + "  - {pos: [0, 0, 0], mass: 1}\n" * 11
    s = load_scene(nine + "springs:\n  - {particle_ids: [000, 010], stiffness: 1}\n")
    assert s.config.steps == 10
    np.testing.assert_array_equal(s.model.spring_indices, [[0, 10]])
    assert load_scene(HEAD.replace("}", ", steps: 0o10}") + "particles: [{pos: [0, 0, 0], mass: 1}]\n").config.steps == 8
    assert load_scene(HEAD.replace("}", ", steps: 0x10}") + "particles: [{pos: [0, 0, 0], mass: 1}]\n").config.steps == 16
    assert load_scene(HEAD.replace("}", ", steps: 1_000}") + "particles: [{pos: [0, 0, 0], mass: 1}]\n").config.steps == 1000
    msg = _err(HEAD.replace("}", ", steps: 1:30}") + "particles: [{pos: [0, 0, 0], mass: 1}]\n")
    assert msg.startswith("solver.steps: must be an integer") and "'1:30'" in msg
    assert "springs[0].particle_ids: particle ids must be integers" in _err(
        TWO + "springs:\n  - {particle_ids: [0, 0:01], stiffness: 1}\n")
    assert "springs[0].stiffness: must be a number" in _err(
        TWO + "springs:\n  - {particle_ids: [0, 1], stiffness: 1:30.5}\n")
    assert load_scene(TWO + "springs:\n  - {particle_ids: [0, 1], stiffness: 007.5}\n").model.spring_stiffness[0] == 7.5


def test_loader_stays_safe_with_yaml_1_2_numbers():
    """The 1.2 number resolvers keep the loader safe: python tags are refused, ``!!int`` follows the same rules."""
    assert "YAML error" in _err(HEAD + "particles: !!python/object/apply:os.getcwd []\n")
    assert load_scene(HEAD.replace("}", ", steps: !!int 012}") + "particles: [{pos: [0, 0, 0], mass: 1}]\n"
                      ).config.steps == 12
    assert "not an integer" in _err(HEAD.replace("}", ", steps: !!int '1:30'}") + "particles: [{pos: [0, 0, 0], mass: 1}]\n")


def test_nan_rest_length_and_softening_are_refused():
    """``.nan`` for ``rest_length`` or ``softening`` is an error naming the item, while absent or null means the default."""
    springs = "springs:\n" + "  - {particle_ids: [0, 1], stiffness: 1}\n" * 3
    assert _err(TWO + springs + "  - {particle_ids: [0, 1], stiffness: 1, rest_length: .nan}\n").startswith(
        "springs[3].rest_length: must be finite")
    msg = _err(TWO + "gravitational:\n  - {particle_ids: [0, 1], G: 1, softening: .NaN}\n")
    assert msg.startswith("gravitational[0].softening: must be finite") and msg.endswith("got nan")
    s = load_scene(TWO + "springs:\n  - {particle_ids: [0, 1], stiffness: 1, rest_length: null}\n"
                   "gravitational:\n  - {particle_ids: [0, 1], G: 1}\n")
    assert s.model.spring_rest_length[0] == 1.0
    assert np.isfinite(s.model.gravitational_softening[0]) and s.model.gravitational_softening[0] > 0


def test_duration_sets_steps():
    """``duration`` becomes a step count, rounded up; steps and duration exclude each other."""
    s = load_scene("solver: {type: midpoint, timestep: 0.03, duration: 0.1}\nparticles: [{pos: [0,0,0], mass: 1}]")
    assert s.config.run_steps() == 4 and s.config.with_overrides(steps=7).run_steps() == 7


def test_solver_options_reach_integrator_options():
    """Linear solver, Jacobian mode and Newton/linear tolerances are passed to make_integrator."""
    s = load_scene("solver: {type: implicit_euler, timestep: 0.01, linear_solver: direct, jacobian: spd,"
                   " linear_rtol: 1.0e-8, newton_tol: 1.0e-7, newton_maxiter: 9, time_rtol: 1.0e-3,"
                   " time_atol: 1.0e-6}\nparticles: [{pos: [0,0,0], mass: 1}]")
    assert s.config.integrator_options() == {"solver": "direct", "jacobian": "spd", "newton_tol": 1e-7,
                                             "newton_maxiter": 9, "linear_rtol": 1e-8}
    assert (s.config.time_rtol, s.config.time_atol) == (1e-3, 1e-6)
    assert s.config.max_step is None
    capped = load_scene("solver: {type: tr_bdf2, timestep: 0.01, time_rtol: 1.0e-3, max_step: 0.004}\n"
                        "particles: [{pos: [0,0,0], mass: 1}]")
    assert capped.config.max_step == 0.004


def test_cloth_generator_matches_gallery_topology():
    """A ``cloth:`` block after explicit particles gives global indices and the gallery's springs."""
    text = HEAD + """
particles: [{pos: [5, 5, 5], mass: 1}]
springs: [{particle_ids: [0, 1], stiffness: 3}]
cloth:
  nx: 4
  ny: 3
  origin: [0, 0, 1]
  spacing: 0.1
  plane: xz
  mass: 0.2
  ke: 100
  kd: 0.5
  ke_y: 200
  bending: false
  pin: corners
"""
    m = load_scene(text).model
    assert m.particle_count == 13
    topo = cloth_grid_pairs(4, 3, bending=False)
    assert m.spring_count == 1 + sum(len(v) for v in topo.values())
    np.testing.assert_array_equal(m.spring_indices[0], [0, 1])
    np.testing.assert_array_equal(m.spring_indices[1:1 + len(topo["structural_x"])], topo["structural_x"] + 1)
    np.testing.assert_allclose(m.particle_q[1 + 5], [0.1, 0, 1.1])
    assert np.count_nonzero(m.particle_fixed) == 2
    np.testing.assert_array_equal(m.particle_mass[1:], 0.2)
    assert set(np.unique(m.spring_stiffness[1:])) == {100.0, 200.0}


def test_cloth_list_and_benchmark_shortcut():
    """``cloth`` accepts a list; ``benchmark_cloth`` needs no timestep and defaults to 1/60 s."""
    s = load_scene("solver: {type: linearized_implicit}\nbenchmark_cloth: {n: 8, kd: 0.5}\n"
                   "cloth:\n  - {nx: 2, ny: 2, pin: none}\n  - {nx: 3, ny: 2, size: [2, 1]}\n")
    assert s.model.particle_count == 4 + 6 + 64
    assert s.config.dt == pytest.approx(1 / 60)
    assert s.model.cloth_grids == ((0, 2, 2), (4, 3, 2), (10, 8, 8))


def test_huge_cloth_generator():
    """A 512 x 512 cloth loads from a generator block of a few lines (counts only, no timing)."""
    s = load_scene("solver: {type: linearized_implicit, timestep: 0.01}\n"
                   "cloth: {nx: 512, ny: 512, ke: 1.0e4, pin: edge}\n")
    n = 512
    assert s.model.particle_count == n * n
    assert s.model.spring_count == 2 * n * (n - 1) + 2 * (n - 1) ** 2 + 2 * n * (n - 2)
    assert np.count_nonzero(s.model.particle_fixed) == n


def test_file_path_and_text_and_pathlike(tmp_path):
    """``load_scene`` takes a str path, a Path, or YAML text; the source and name are recorded."""
    f = tmp_path / "my_scene.yaml"
    f.write_text(TWO)
    for arg in (str(f), f):
        s = load_scene(arg)
        assert s.source == str(f) and s.name == "my_scene" and s.model.particle_count == 2


def test_parse_scene_takes_a_dict():
    """``parse_scene`` validates an already-parsed document."""
    doc = {"solver": {"type": "midpoint", "timestep": 0.1}, "particles": [{"pos": [0, 0, 0], "mass": 1}]}
    assert parse_scene(doc).model.particle_count == 1


BAD = [
    # (text, expected fragment of the one-line message)
    ("", "<string>: empty scene file"),
    ("# only a comment\n", "empty scene file"),
    ("[1, 2]", "top level must be a mapping"),
    ("42", "top level must be a mapping"),
    ("solver: {type: midpoint\n", "YAML syntax error at line 2"),
    ("a: b: c\n", "YAML syntax error at line 1"),
    (TWO + "colour: red\n", "unknown top-level key 'colour'"),
    (TWO.replace("mass: 2}", "mass: 2, colour: red}"), "particles[1]: unknown key 'colour'"),
    (HEAD.replace("}", ", bogus: 1}") + "particles: [{pos: [0,0,0], mass: 1}]", "solver: unknown key 'bogus'"),
    ("particles: [{pos: [0,0,0], mass: 1}]", "solver: missing required block"),
    ("solver: {timestep: 0.1}\nparticles: [{pos: [0,0,0], mass: 1}]", "solver: missing required key 'type'"),
    ("solver: {type: midpoint}\nparticles: [{pos: [0,0,0], mass: 1}]", "solver: missing required key 'timestep'"),
    ("solver: {type: rk99, timestep: 0.1}\nparticles: [{pos: [0,0,0], mass: 1}]",
     "solver.type: unknown integrator 'rk99'; choose one of explicit_euler"),
    (HEAD.replace("}", ", linear_solver: magic}") + "particles: [{pos: [0,0,0], mass: 1}]",
     "solver.linear_solver: unknown linear solver 'magic'; choose one of"),
    (HEAD.replace("}", ", jacobian: wrong}") + "particles: [{pos: [0,0,0], mass: 1}]",
     "solver.jacobian: unknown jacobian mode 'wrong'; choose one of exact"),
    ("solver: {type: midpoint, timestep: -0.1}\nparticles: [{pos: [0,0,0], mass: 1}]",
     "solver.timestep: must be > 0, got -0.1"),
    ("solver: {type: midpoint, timestep: .inf}\nparticles: [{pos: [0,0,0], mass: 1}]", "solver.timestep"),
    ("solver: {type: midpoint, timestep: '0.1'}\nparticles: [{pos: [0,0,0], mass: 1}]",
     "solver.timestep: must be a number, got str '0.1'"),
    (HEAD.replace("}", ", gravity: .nan}") + "particles: [{pos: [0,0,0], mass: 1}]", "solver.gravity: must be finite"),
    (HEAD.replace("}", ", up_axis: w}") + "particles: [{pos: [0,0,0], mass: 1}]", "solver.up_axis"),
    (HEAD.replace("}", ", newton_maxiter: 2.5}") + "particles: [{pos: [0,0,0], mass: 1}]",
     "solver.newton_maxiter: must be an integer, got float 2.5"),
    (HEAD.replace("}", ", newton_tol: 0}") + "particles: [{pos: [0,0,0], mass: 1}]", "solver.newton_tol"),
    (HEAD.replace("}", ", time_rtol: -1}") + "particles: [{pos: [0,0,0], mass: 1}]", "solver.time_rtol"),
    (HEAD.replace("}", ", max_step: -0.01}") + "particles: [{pos: [0,0,0], mass: 1}]",
     "solver.max_step: must be >= 1e-07, got -0.01"),
    (HEAD.replace("}", ", steps: 3, duration: 1}") + "particles: [{pos: [0,0,0], mass: 1}]",
     "steps or duration, not both"),
    (HEAD, "no particles"),
    (HEAD + "particles: 3", "particles: must be a list"),
    (HEAD + "particles: [3]", "particles[0]: must be a mapping"),
    (HEAD + "particles: [{pos: [0,0,0]}]", "particles[0]: missing required key 'mass'"),
    (HEAD + "particles: [{mass: 1}]", "particles[0]: missing required key 'pos'"),
    (HEAD + "particles: [{pos: 1, mass: 1}]", "particles[0].pos: must be a list of 3 numbers"),
    (HEAD + "particles: [{pos: [0, 0], mass: 1}]", "particles[0].pos: must have 3 components, got 2"),
    (HEAD + "particles: [{pos: [0, x, 0], mass: 1}]", "particles[0].pos[1]: must be a number, got a string"),
    (HEAD + "particles: [{pos: [0, true, 0], mass: 1}]", "particles[0].pos[1]: must be a number, got a boolean"),
    (HEAD + "particles: [{pos: [0, 0, .nan], mass: 1}]", "particles[0].pos: must be finite"),
    (HEAD + "particles: [{pos: [0, 0, 0], vel: [0, 0, -.inf], mass: 1}]", "particles[0].vel: must be finite"),
    (HEAD + "particles: [{pos: [0, 0, 0], mass: 0}]", "particles[0].mass: must be > 0, got 0"),
    (HEAD + "particles: [{pos: [0,0,0], mass: 1}, {pos: [0,0,0], mass: -2}]", "particles[1].mass: must be > 0"),
    (HEAD + "particles: [{pos: [0, 0, 0], mass: '1'}]", "particles[0].mass: must be a number, got a string"),
    (HEAD + "particles: [{pos: [0, 0, 0], mass: true}]", "particles[0].mass: must be a number, got a boolean"),
    (HEAD + "particles: [{pos: [0, 0, 0], mass: 1, fixed: 1}]", "particles[0].fixed: must be true or false"),
    (HEAD + "particles: [{pos: [0, 0, 0], mass: 1, drag: -1}]", "particles[0].drag: must be >= 0"),
    (HEAD + "particles: [{pos: [0, 0, 0], mass: 1, radius: -1}]", "particles[0].radius: must be >= 0"),
    (TWO + "springs: [{particle_ids: [0, 1]}]", "springs[0]: missing required key 'stiffness'"),
    (TWO + "springs: [{stiffness: 1}]", "springs[0]: missing required key 'particle_ids'"),
    (TWO + "springs: [{particle_ids: [0, 1], stiffness: -1}]", "springs[0].stiffness: must be >= 0, got -1"),
    (TWO + "springs: [{particle_ids: [0, 1], stiffness: 1, damping: -0.5}]", "springs[0].damping: must be >= 0"),
    (TWO + "springs: [{particle_ids: [0, 1], stiffness: 1, rest_length: -1}]", "springs[0].rest_length"),
    (TWO + "springs: [{particle_ids: [0, 1], stiffness: .inf}]", "springs[0].stiffness: must be finite"),
    (TWO + "springs: [{particle_ids: [0, 2], stiffness: 1}]", "springs[0].particle_ids: particle id out of range"),
    (TWO + "springs: [{particle_ids: [-1, 0], stiffness: 1}]", "springs[0].particle_ids: particle id out of range"),
    (TWO + "springs: [{particle_ids: [0, 1.5], stiffness: 1}]", "springs[0].particle_ids: particle ids must be int"),
    (TWO + "springs: [{particle_ids: [0, 1, 1], stiffness: 1}]", "springs[0].particle_ids: must have 2"),
    (TWO + "springs: [{particle_ids: 0, stiffness: 1}]", "springs[0].particle_ids: must be a list of 2"),
    (TWO + "springs: [{particle_ids: [1, 1], stiffness: 1}]", "springs[0].particle_ids: a pair needs two different"),
    (TWO + "gravitational: [{particle_ids: [0, 1], G: -1}]", "gravitational[0].G: must be >= 0"),
    (TWO + "gravitational: [{particle_ids: [0, 1]}]", "gravitational[0]: missing required key 'G'"),
    (TWO + "gravitational: [{particle_ids: [0, 0], G: 1}]", "gravitational[0].particle_ids: a pair needs two"),
    (TWO + "plot: {particle_id: 2, dof: 0}", "plot.particle_id: must be an integer particle id in [0, 2)"),
    (TWO + "plot: {particle_id: 1, dof: 3}", "plot.dof: must be 0, 1 or 2"),
    (TWO + "plot: {particle_id: 1, dof: 0, y_range: [1, 0]}", "plot.y_range: needs lo < hi"),
    (TWO + "plot: {particle_id: 1, dof: 0, y_range: 1}", "plot.y_range: must be a list of 2 numbers"),
    (TWO + "plot: {particle_id: 1, dof: 0, color: red}", "plot: unknown key 'color'"),
    (HEAD + "cloth: {nx: 1, ny: 4}", "cloth.nx: must be an integer in [2, 50000000], got 1"),
    (HEAD + "cloth: {nx: 3}", "cloth: missing required key 'ny'"),
    (HEAD + "cloth: [{nx: 3, ny: 3}, {nx: 3, ny: 3, ke: -1}]", "cloth[1].ke: must be >= 0"),
    (HEAD + "cloth: {nx: 3, ny: 3, pin: topp}", "cloth.pin: unknown pin name 'topp'; choose one of none, edge, "),
    (HEAD + "cloth: {nx: 3, ny: 3, pin: [top, 9]}", "cloth.pin[1]: particle index out of range [0, 9), got 9"),
    (HEAD + "cloth: {nx: 3, ny: 3, pin: {box: [[0, 0, 1], [1, 1, 0]]}}", "cloth.pin.box: needs min <= max"),
    (HEAD + "cloth: {nx: 3, ny: 3, ke: 1, stiffness: 1}", "cloth: give stiffness or its alias ke, not both"),
    (TWO + "springs: [{particle_ids: [0, 1], stiffness: 1, ke: 1}]", "springs[0]: give stiffness or its alias ke"),
    (TWO + "springs: [{particle_ids: [0, 1], ke: -1}]", "springs[0].ke: must be >= 0, got -1"),
    (TWO + "pin: [0, 2]", "pin[1]: particle index out of range [0, 2), got 2"),
    (HEAD + "cloth: {nx: 3, ny: 3, plane: ab}", "cloth.plane: must be one of xy, xz, yz, got 'ab'"),
    (HEAD + "cloth: {nx: 3, ny: 3, spacing: 0.1, size: [1, 1]}", "cloth: give spacing or size"),
    (HEAD + "cloth: {nx: 3, ny: 3, size: [1, 0]}", "cloth.size[1]: must be > 0"),
    (HEAD + "cloth: {nx: 3, ny: 3, mass: 0}", "cloth.mass: must be > 0"),
    (HEAD + "cloth: {nx: 3, ny: 3, origin: [0, 0, .nan]}", "cloth.origin[2]: must be finite"),
    (HEAD + "cloth: {nx: 3, ny: 3, wind: 1}", "cloth: unknown key 'wind'"),
    (HEAD + "cloth: 3", "cloth: must be a mapping or a list"),
    (HEAD + "benchmark_cloth: {n: 1.5}", "benchmark_cloth.n: must be an integer in [2, 50000000], got 1.5"),
    (HEAD + "benchmark_cloth: {n: 4, kd: -1}", "benchmark_cloth.kd: must be >= 0"),
    (HEAD + "name: 3\nparticles: [{pos: [0,0,0], mass: 1}]", "name: must be a string"),
]


@pytest.mark.parametrize("text, fragment", BAD, ids=[f"bad{k}" for k in range(len(BAD))])
def test_bad_input_one_line_scene_error(text, fragment):
    """Every invalid input raises a SceneError (a ValueError) with a one-line message naming the field."""
    msg = _err(text)
    assert fragment in msg, msg


def test_missing_file_and_directory(tmp_path):
    """A missing file or a directory is a SceneError naming the path."""
    with pytest.raises(SceneError, match="no such file"):
        load_scene(tmp_path / "nope.yaml")
    with pytest.raises(SceneError, match="is a directory"):
        load_scene(tmp_path)


def test_scene_error_is_value_error_with_path():
    """SceneError is a ValueError and carries the field path."""
    with pytest.raises(ValueError) as info:
        load_scene(TWO + "springs: [{particle_ids: [0, 1], stiffness: -1}]")
    assert info.value.path == "springs[0].stiffness"


def test_registries_are_read_at_call_time(monkeypatch):
    """Names registered after import (by later issues) are accepted by the loader."""
    from springsim.integrators import INTEGRATORS
    from springsim.linsolve import LINEAR_SOLVERS

    monkeypatch.setitem(INTEGRATORS, "my_integrator", INTEGRATORS["midpoint"])
    monkeypatch.setitem(LINEAR_SOLVERS, "my_solver", LINEAR_SOLVERS["direct"])
    s = load_scene("solver: {type: my_integrator, timestep: 0.1, linear_solver: my_solver}\n"
                   "particles: [{pos: [0,0,0], mass: 1}]")
    assert s.config.integrator == "my_integrator" and s.config.linear_solver == "my_solver"


def test_with_overrides_validates():
    """CLI-style overrides are applied and validated like the file's values."""
    cfg = SolverConfig(integrator="midpoint", dt=0.1)
    assert cfg.with_overrides(dt=0.2, integrator=None).dt == 0.2
    with pytest.raises(SceneError, match="solver.type: unknown integrator 'nope'"):
        cfg.with_overrides(integrator="nope")


def test_options_are_declared_once():
    """Every SolverConfig field (its groups' included) is a YAML key of the solver block, a run flag (where it
    declares one) and an integrator or driver option: one declaration serves all three."""
    import argparse

    from springsim.cli.run import add_run_options
    from springsim.run.options import SolverConfig

    p = argparse.ArgumentParser()
    add_run_options(p)
    flags = {a.dest for a in p._actions}
    for name, (_, f) in SolverConfig.declarations().items():
        m = f.metadata
        assert m["help"] and m["kind"] in ("name", "float", "int", "bool", "options")
        assert (f.name in flags) == bool(m["cli"])
    cfg = load_scene("solver: {type: bdf2, timestep: 0.01, residual_rtol: 1.0e-4, linear_rtol: 1.0e-7, "
                     "newton_maxiter: 7}\nparticles: [{pos: [0,0,0], mass: 1}]").config
    assert cfg.integrator_options() == {"residual_rtol": 1e-4, "linear_rtol": 1e-7, "newton_maxiter": 7}


def test_unused_options_are_named(recwarn):
    """Options the chosen integrator ignores are warned about by name (never dropped silently)."""
    from springsim.errors import UnusedOptionWarning
    from springsim.integrators import make_integrator

    m = load_scene("solver: {type: midpoint, timestep: 0.01}\nparticles: [{pos: [0,0,0], mass: 1}]").model
    with pytest.warns(UnusedOptionWarning, match="symplectic_euler does not use the option.s. jacobian, newton_tol"):
        make_integrator("symplectic_euler", m, jacobian="exact", newton_tol=1e-6)
    with pytest.warns(UnusedOptionWarning, match="linearized_implicit does not use the option.s. newton_maxiter"):
        make_integrator("linearized_implicit", m, newton_maxiter=3)
    cfg = load_scene("solver: {type: linearized_implicit, timestep: 0.01, newton_tol: 1.0e-6, max_step: 0.1}\n"
                     "particles: [{pos: [0,0,0], mass: 1}]").config
    assert cfg.unused() == ["max_step", "newton_tol"]


def test_generator_scene_is_described_and_built_only_on_request():
    """A scene of one generator block carries its description (Scene.generator), from which a rank's part of the
    model is exactly that rank's share of the built model; with build=False the model is not built; any other
    scene (explicit particles, a pin, two blocks) has no description and is always built."""
    from springsim.distributed import generated_part, model_part

    text = "solver: {type: implicit_euler, timestep: 0.01, gravity: -3}\nbenchmark_cloth: {n: 6, ke: 2.0e+3}\n"
    built, lazy = load_scene(text), load_scene(text, build=False)
    assert lazy.model is None and lazy.generator == built.generator and built.generator["gravity"] == -3
    for rank in range(3):
        g, m = generated_part(lazy.generator, 3, rank), model_part(built.model, 3, rank)
        assert g.particle_count == m.particle_count == 36 and g.pair_counts == m.pair_counts
        np.testing.assert_array_equal(g.part.local_particles, m.part.local_particles)
        for a, b in ((g.part.pair_model, m.part.pair_model), (g.part.particle_model, m.part.particle_model)):
            assert a.fingerprint() == b.fingerprint()
        assert g.fingerprint() == built.model.fingerprint()  # hashed in bands, no rank holding the model
    for other in ("particles: [{pos: [5, 0, 0], mass: 1}]\n", "pin: [0]\n",
                  "cloth: {nx: 3, ny: 3}\n"):
        s = load_scene(text + other, build=False)
        assert s.generator is None and s.model is not None
    bad = load_scene(text.replace("2.0e+3", "-3"), build=False)  # checked where the parts are generated
    with pytest.raises(SceneError, match=r"^benchmark_cloth\.ke: must be >= 0, got -3"):
        generated_part(bad.generator, 2, 1)


@pytest.mark.parametrize("piece", [1 << 16, 7, 1])
@pytest.mark.parametrize("grid, gravity, up", [
    (dict(nx=5, ny=4), -9.81, "z"),
    (dict(nx=2, ny=2), -9.81, "z"),
    (dict(nx=2, ny=7, bending=False), -3.0, "y"),
    (dict(nx=7, ny=2, pin="none"), -9.81, 0),
    (dict(nx=9, ny=11, plane="xz", drag=0.3, ke=1e5, kd=2.0, ke_shear=10, ke_bend=3.0, pin="corners"), -1.0, "y"),
    (dict(nx=6, ny=6, size=(1.0, 2.0), total_mass=3.0, origin=(1.0, 2.0, 3.0),
          pin={"box": [[0, 0, 0], [1.5, 2.5, 4]]}), -9.81, "z"),
])
def test_cloth_grid_fingerprint_streamed_in_bands_is_the_models(grid, gravity, up, piece, monkeypatch):
    """A generated cloth's fingerprint, hashed in bands of rows without building the model (down to one row per
    piece), is the built model's to the bit: every array, pin and coefficient variant, family order, plane."""
    from springsim.distributed import scene as ds

    monkeypatch.setattr(ds, "FINGERPRINT_PIECE", piece)
    b = ModelBuilder(gravity=gravity, up_axis=up)
    b.add_cloth_grid(**grid)
    assert ds.cloth_grid_fingerprint(grid, gravity=gravity, up_axis=up) == b.finalize().fingerprint()


def test_streamed_fingerprint_checks_its_pieces():
    """Pieces that do not make the declared array are refused, not hashed as another array."""
    from springsim.model.model import streamed_fingerprint

    kw = dict(gravity=0.0, up_axis=2, pair_epsilon=1e-9, cloth_grids=())
    with pytest.raises(ValueError, match="the pieces have 2 rows, declared 3"):
        streamed_fingerprint([("a", (3,), np.float64, [np.zeros(2)])], **kw)
    with pytest.raises(ValueError, match="a piece of dtype int64"):
        streamed_fingerprint([("a", (2,), np.float64, [np.zeros(2, dtype=np.int64)])], **kw)
