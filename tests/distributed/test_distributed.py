"""The petsc backend against the serial path: partition, forces, the gathered matrix, trajectories of every
integrator on 1, 2 and 3 ranks, and failure paths that end every rank with one message (each bounded by a timeout).

The partition tests are plain numpy and always run. The others need petsc4py, mpi4py and ``mpiexec``; they are
skipped where those are absent unless ``SPRINGSIM_REQUIRE_PETSC=1`` (set by ``.ci/run``'s distributed stage), where
their absence fails them.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from springsim.distributed import contiguous_offsets, partition
from springsim.forces import eval_forces, make_force_terms

from .scenes import scene
from .mpi_cases import STAGE_TOLERANCE

ROOT = Path(__file__).resolve().parents[2]
TIMEOUT = 180  # s: a hang fails the test instead of the suite


def _petsc_reason() -> str | None:
    from springsim.distributed import petsc_available

    if not petsc_available():
        return "petsc4py/mpi4py not importable (docs/distributed.md)"
    if shutil.which("mpiexec") is None:
        return "no mpiexec on PATH"
    return None


_REASON = _petsc_reason()
if _REASON and os.environ.get("SPRINGSIM_REQUIRE_PETSC") == "1":
    needs_petsc = pytest.mark.usefixtures()  # run anyway: the tests then fail with the reason

    def _fail():
        pytest.fail(f"SPRINGSIM_REQUIRE_PETSC=1 but {_REASON}")
else:
    needs_petsc = pytest.mark.skipif(_REASON is not None, reason=_REASON or "")

    def _fail():
        pass


def mpirun(n: int, *args, check: bool = True) -> subprocess.CompletedProcess:
    """``mpiexec -n n python -m tests.distributed.mpi_cases *args`` (or a command, when args[0] is a list)."""
    _fail()
    cmd = ["mpiexec", "--oversubscribe", "--quiet", "-n", str(n)]
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        cmd.insert(1, "--allow-run-as-root")  # Open MPI refuses root without it
    cmd += list(args[0]) if isinstance(args[0], list) else [sys.executable, "-m", "tests.distributed.mpi_cases", *args]
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    r = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=TIMEOUT)
    if check and r.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} exited {r.returncode}\n{r.stdout}\n{r.stderr}")
    return r


# -- partition (numpy only) -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("size", [1, 2, 3, 5])
@pytest.mark.parametrize("name", ["cloth", "irregular"])
def test_partition_covers_everything_once(name, size):
    model = scene(name)
    free = model.free_particles
    owned, pairs = [], {"spring": [], "gravitational": []}
    for r in range(size):
        p = partition(model, size, r)
        owned.append(p.local_particles[:p.n_own])
        for k, v in p.owned_pairs.items():
            pairs[k].append(v)
        assert np.all(p.local_to_free[:p.n_local_free] >= 0) and np.all(p.local_to_free[p.n_local_free:] == -1)
        assert np.array_equal(p.local_to_free[:p.n_own], np.arange(p.lo, p.hi))
        assert p.pair_model.gravity == 0.0 and not p.pair_model.particle_drag.any()
        assert p.particle_model.spring_count == 0 and p.particle_model.particle_count == p.n_own
    assert np.array_equal(np.concatenate(owned), free)  # contiguous blocks, in the serial system's order
    fixed = model.particle_fixed
    for k, ij in (("spring", model.spring_indices), ("gravitational", model.gravitational_indices)):
        active = np.flatnonzero(~(fixed[ij[:, 0]] & fixed[ij[:, 1]]))
        assert np.array_equal(np.sort(np.concatenate(pairs[k])), active)


@pytest.mark.parametrize("size", [1, 2, 4])
@pytest.mark.parametrize("name", ["cloth", "irregular"])
def test_local_forces_sum_to_the_serial_forces(name, size):
    """Pairwise terms on the owned pairs (ghost rows sent to their owners) plus per-particle terms on the owned
    particles give the serial forces, to round-off (only the order of the sums differs)."""
    model = scene(name)
    _check_summed_forces(model, [partition(model, size, r) for r in range(size)])


def _check_summed_forces(model, parts):
    """Every part's local forces, ghost rows added to their owners, equal the serial forces to round-off."""
    from .mpi_cases import _state

    q, v = _state(model)
    ref = eval_forces(make_force_terms(model), q, v)
    total = np.zeros_like(ref)
    for p in parts:
        ql, vl = q[p.local_particles], v[p.local_particles]
        f = np.zeros_like(ql)
        for t in make_force_terms(p.pair_model):
            assert t.pairwise
            t.eval_force(ql, vl, f)
        for t in make_force_terms(p.particle_model):
            assert not t.pairwise
            t.eval_force(ql[:p.n_own], vl[:p.n_own], f[:p.n_own])
        np.add.at(total, p.local_particles[:p.n_local_free], f[:p.n_local_free])
    free = model.free_particles
    assert np.abs(total[free] - ref[free]).max() <= 1e-12 * np.abs(ref).max()


def test_contiguous_offsets():
    assert contiguous_offsets(10, 3).tolist() == [0, 4, 7, 10]
    assert contiguous_offsets(2, 4).tolist() == [0, 1, 2, 2, 2]
    with pytest.raises(ValueError):
        contiguous_offsets(3, 0)


# -- PETSc: matrix, trajectories --------------------------------------------------------------------------------------
MATRIX_CASES = ([(name, ranks, "contiguous") for name in ("cloth", "irregular") for ranks in (1, 2, 3)]
                + [(name, ranks, "ptscotch") for name in ("irregular", "shuffled_cloth") for ranks in (2, 3)])


@needs_petsc
@pytest.mark.parametrize("name, ranks, partitioner", MATRIX_CASES)
def test_gathered_matrix_equals_serial(name, ranks, partitioner, tmp_path):
    """Contiguous blocks: the gathered matrix is the serial one; a graph partition numbers the system part by
    part, and the gathered matrix is the serial one with rows and columns permuted alike. The first matrix is
    inserted by PETSc, the second directly into the AIJ arrays (springsim.distributed._aij)."""
    from springsim.assembly import SystemAssembler

    from .mpi_cases import _state

    out = tmp_path / "m.npz"
    mpirun(ranks, "matrix", name, str(out), partitioner)
    d = np.load(out)
    model = scene(name)
    q, v = _state(model)
    terms = make_force_terms(model)
    f = eval_forces(terms, q, v)[model.free_particles]
    assert int(d["size"]) == ranks
    assert bool(d["direct"])  # the direct insertion reproduced PETSc's on the first matrix and was kept
    assert np.abs(d["f"] - f).max() <= 1e-12 * np.abs(f).max()
    # the second-order correction's forces (length remainders from q to another state) match the serial terms'
    q2, _ = _state(model, seed=11)
    curv = np.zeros_like(q)
    for t in terms:
        t.curvature_remainder(q, q2, curv)
    assert ("curvature" in d.files) == any(t.curved for t in terms)
    if "curvature" in d.files:
        curv = curv[model.free_particles]
        assert np.abs(d["curvature"] - curv).max() <= 1e-12 * np.abs(curv).max()
    asm = SystemAssembler(model, terms)
    free_index = np.full(model.particle_count, -1)
    free_index[model.free_particles] = np.arange(model.free_count)
    rows = free_index[d["system_particles"]]  # serial block row of every system row
    assert sorted(rows) == list(range(model.free_count))
    if partitioner == "contiguous":
        assert np.array_equal(rows, np.arange(model.free_count))
    dofs = (3 * rows[:, None] + np.arange(3)).ravel()
    for mode in ("exact", "spd"):
        S = asm.assemble(q, v, 2.5e-4, 1.6e-2, mode).tocsr()[dofs][:, dofs]
        A = sp.csr_matrix((d[f"{mode}_data"], d[f"{mode}_indices"], d[f"{mode}_indptr"]), shape=S.shape)
        assert abs(A - S).max() <= 1e-13 * abs(S).max(), mode


# symplectic Euler: the same operations up to the order of the force sums, so agreement to round-off. Implicit: every
# KSP solve meets rtol 1e-10 on the true residual while the serial reference solves directly, so each velocity update
# differs by at most cond(A) * 1e-10 relative; cond(A) <= 1e3 on these systems (the mass dominates at these steps),
# hence the 1e-7 m bound over the run (measured: 1e-12 ... 1e-10 m).
@needs_petsc
def test_graph_partition_has_fewer_ghosts_on_a_scattered_numbering(tmp_path):
    """On a cloth numbered at random, contiguous blocks of the numbering are scattered over the cloth; PT-Scotch's
    parts are compact (measured: 219 ghosts in all against 50 on 3 ranks)."""
    ghosts = {}
    for partitioner in ("contiguous", "ptscotch"):
        mpirun(3, "matrix", "shuffled_cloth", str(tmp_path / f"{partitioner}.npz"), partitioner)
        ghosts[partitioner] = int(np.load(tmp_path / f"{partitioner}.npz")["ghosts"].sum())
    assert ghosts["ptscotch"] < ghosts["contiguous"] / 2


CASES = [("cloth", "symplectic_euler", 1e-4, 30, 1e-12), ("irregular", "symplectic_euler", 1e-3, 30, 1e-12),
         ("cloth", "linearized_implicit", 1 / 60, 10, 1e-7), ("irregular", "linearized_implicit", 1e-2, 10, 1e-7),
         ("cloth", "implicit_euler", 1 / 60, 5, 1e-7), ("irregular", "implicit_euler", 1e-2, 5, 1e-7),
         ("irregular", "midpoint", 1e-3, 10, 1e-12), ("irregular", "explicit_euler", 1e-4, 10, 1e-12),
         ("cloth", "bdf2", 1 / 60, 5, 1e-7), ("cloth", "tr_bdf2", 1 / 60, 5, 1e-7),
         ("irregular", "energy_momentum", 1e-2, 5, 1e-7)]
IMPLICIT = ("linearized_implicit", "implicit_euler", "bdf2", "tr_bdf2", "energy_momentum")


TRAJECTORY_CASES = ([(*c, ranks, "contiguous") for c in CASES for ranks in (1, 2, 3)]
                    + [(*c, 2, "ptscotch") for c in CASES if c[0] == "irregular" and c[1] in ("symplectic_euler",
                                                                                           "implicit_euler")]
                    + [("shuffled_cloth", "linearized_implicit", 1 / 60, 10, 1e-7, 3, "ptscotch")])


@needs_petsc
@pytest.mark.parametrize("name, integrator, dt, steps, bound, ranks, partitioner", TRAJECTORY_CASES)
def test_trajectory_matches_serial(name, integrator, dt, steps, bound, ranks, partitioner, tmp_path):
    from springsim import simulate
    from springsim.integrators import make_integrator

    out = tmp_path / "t.npz"
    mpirun(ranks, "trajectory", name, integrator, repr(dt), str(steps), str(out), partitioner)
    d = np.load(out)
    model = scene(name)
    implicit = integrator in IMPLICIT
    opts = dict(solver="direct", jacobian="spd", on_nonconvergence="ignore") if implicit else {}
    opts.update(STAGE_TOLERANCE.get(integrator, {}))
    ref = simulate(model, make_integrator(integrator, model, **opts), dt, steps)
    assert d["q"].shape == ref.q.shape
    scale = np.abs(ref.q).max()
    assert np.abs(d["q"] - ref.q).max() <= bound * max(scale, 1.0)
    if implicit:
        # the same iterations, but for one more or less where a stage meets its tolerance at the round-off of the
        # two linear solvers (KSP to 1e-10 against direct)
        assert np.abs(np.array(d["newton"]) - [s.newton_iterations for s in ref.stats]).max() <= 1
        assert list(d["ok"]) == [s.ok for s in ref.stats]


@needs_petsc
@pytest.mark.parametrize("integrator", ["bdf2", "tr_bdf2", "energy_momentum"])
@pytest.mark.parametrize("ranks", [1, 2, 3])
def test_adaptive_matches_serial(integrator, ranks, tmp_path):
    """Adaptive stepping (the one controller, :func:`springsim.simulate_adaptive`) over the PETSc system takes the
    same steps as the serial run and lands on the same frames within the linear tolerance's effect."""
    from springsim import simulate_adaptive

    out = tmp_path / "a.npz"
    mpirun(ranks, "adaptive", "cloth", integrator, str(out))
    d = np.load(out)
    model = scene("cloth")
    ref = simulate_adaptive(model, integrator, 0.2, frame_dt=0.05, time_rtol=1e-3, time_atol=1e-4, h0=1e-2,
                            solver="direct", jacobian="spd", on_nonconvergence="ignore")
    assert d["q"].shape == ref.q.shape
    assert int(d["accepted"]) == ref.adaptive_stats["accepted"] and int(d["rejected"]) == ref.adaptive_stats["rejected"]
    assert np.abs(d["q"] - ref.q).max() <= 1e-6 * max(np.abs(ref.q).max(), 1.0)


@needs_petsc
@pytest.mark.parametrize("integrator", ["implicit_euler", "linearized_implicit", "tr_bdf2"])
def test_cli_defaults_match_serial(integrator, tmp_path):
    """The same command with the same (default) options gives the same frames on either backend: a course-style
    10 x 20 cloth, no solver options, serial against ``mpiexec -n 2 ... --backend petsc``; the defaults (stage
    rule, Jacobian mode, Newton and linear tolerances) are one set, so the trajectories differ only by the linear
    solves (KSP to rtol 1e-6 against a direct solve) as seen through the converged stages."""
    scene_path = tmp_path / "cloth.yaml"
    scene_path.write_text(f"solver: {{type: {integrator}, timestep: 0.0166667, steps: 10}}\n"
                          "benchmark_cloth: {n: 10}\n")
    out = tmp_path / "d.npz"
    mpirun(2, [sys.executable, "-m", "springsim", "run", str(scene_path), "--backend", "petsc", "--out", str(out),
               "-q"])
    r = subprocess.run([sys.executable, "-m", "springsim", "run", str(scene_path), "--out", str(tmp_path / "s.npz"),
                        "-q"], cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT)
    assert r.returncode == 0, r.stderr
    d, s = np.load(out), np.load(tmp_path / "s.npz")
    assert d["q"].shape == s["q"].shape
    assert np.abs(d["q"] - s["q"]).max() < 1e-5


@needs_petsc
def test_eisenstat_walker_forcing_matches_serial(tmp_path):
    """Inexact Newton (Eisenstat-Walker forcing terms in the KSP tolerance) on 2 ranks converges every stage to the
    serial direct-solve trajectory within the Newton tolerance (1e-9 m/s here, so 1e-7 m over the run), with looser
    solves than the fixed 1e-10 at the first iterations."""
    from springsim import simulate
    from springsim.integrators import make_integrator

    out = tmp_path / "t.npz"
    mpirun(2, "trajectory_forcing", "cloth", repr(1 / 60), "5", str(out))
    d = np.load(out)
    model = scene("cloth")
    ref = simulate(model, make_integrator("implicit_euler", model, solver="direct", jacobian="spd",
                                          stage_solver="residual", newton_tol=1e-9,
                                          newton_maxiter=20), 1 / 60, 5)
    assert all(d["ok"]) and all(s.ok for s in ref.stats)
    assert np.abs(d["q"] - ref.q).max() <= 1e-7 * max(np.abs(ref.q).max(), 1.0)
    assert d["linres"].max() > 1e-6


@needs_petsc
def test_cli_two_ranks_matches_serial_run(tmp_path):
    """``mpiexec -n 2 springsim run --backend petsc --out``: rank 0 alone reads, prints and writes (the frames
    streamed), the frames match a serial run of the same scene (linearized implicit Euler, AMG-CG against KSP CG + GAMG, both at rtol 1e-10)."""
    from springsim.cli import main

    scene_path = tmp_path / "cloth.yaml"
    scene_path.write_text("solver: {type: linearized_implicit, timestep: 0.0166667, steps: 4, jacobian: spd, "
                          "linear_rtol: 1.0e-10}\nbenchmark_cloth: {n: 12}\n")
    out = tmp_path / "d.npz"
    r = mpirun(2, [sys.executable, "-m", "springsim", "run", str(scene_path), "--backend", "petsc", "--out", str(out)])
    assert r.stdout.count("backend:") == 1 and "petsc, 2 MPI rank(s)" in r.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cloth.yaml", "d.npz"]  # streamed: no spool left
    assert re.search(r"failed steps:\s+0 ", r.stdout)
    assert main(["run", str(scene_path), "--out", str(tmp_path / "s.npz"), "-q"]) == 0
    d, s = np.load(out), np.load(tmp_path / "s.npz")
    assert d["q"].shape == s["q"].shape == (5, 144, 3)
    assert np.abs(d["q"] - s["q"]).max() < 1e-7


# -- failure paths -------------------------------------------------------------------------------------------------
@needs_petsc
def test_bad_input_one_message_on_every_rank(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("solver: {type: linearized_implicit, timestep: 0.01, backend: petsc}\nparticles:\n"
                   "  - {pos: [0, 0, 0], mass: 1}\n  - {pos: [1, 0, 0], mass: 1}\n"
                   "springs:\n  - {particle_ids: [0, 1], stiffness: -3}\n")
    r = mpirun(2, [sys.executable, "-m", "springsim", "run", str(bad)], check=False)
    assert r.returncode == 2
    lines = [x for x in r.stderr.splitlines() if x.startswith("springsim:")]
    assert lines == [f"springsim: error: {bad}: springs[0].stiffness: must be >= 0, got -3"]


def _matches_serial_run(scene_path, out, shape, tol):
    """The frames in ``out`` (a distributed run of ``scene_path``) are a serial run's of the same scene (written next
    to ``out``) to ``tol``, of ``shape``, with the same model fingerprint."""
    from springsim.cli import main
    from springsim.run.driver import Trajectory

    serial = out.parent / ("serial_" + out.name)
    assert main(["run", str(scene_path), "--out", str(serial), "-q"]) == 0
    d, s = Trajectory.load(out), Trajectory.load(serial)
    assert d.q.shape == s.q.shape == shape
    assert np.abs(d.q - s.q).max() < tol
    assert d.meta["model_fingerprint"] == s.meta["model_fingerprint"] is not None


@needs_petsc
@pytest.mark.parametrize("ranks", [2, 3])
@pytest.mark.parametrize("name, chunk", [("mixed", 3), ("mixed", 1 << 16), ("mixed_cloths", 5), ("two_cloths", 5),
                                         ("small_cloth", 7)])
def test_scene_read_in_pieces_is_the_models_part(name, chunk, ranks, tmp_path):
    """A scene file with item lists (and generator blocks beside them), read on rank 0 in chunks and sent on in
    pieces (chunks that straddle the ranks' blocks, and one chunk for everything): every rank's part is the whole
    model's to the last bit (mpi_cases read_in_pieces). One rank: tests/unit/test_scene_stream.py."""
    from helpers import TWO_CLOTHS_YAML, mixed_scene_yaml

    path = tmp_path / "s.yaml"
    path.write_text(mixed_scene_yaml(cloths=name == "mixed_cloths") if name.startswith("mixed") else
                    TWO_CLOTHS_YAML if name == "two_cloths" else (ROOT / "scenes" / f"{name}.yaml").read_text())
    mpirun(ranks, "read_in_pieces", str(path), str(chunk))


@needs_petsc
def test_cli_scene_with_lists_is_read_in_pieces(tmp_path):
    """``mpiexec -n 2 springsim run`` of a scene file with item lists and generator blocks: read on rank 0 in pieces,
    the cloths generated there a band at a time, no rank building the model; the frames are the serial run's and
    the fingerprint the serial model's; an error that only rank 1's block meets (a computed value's rule, checked
    where the pair is held) is one line naming the item as a serial run does, exit 2."""
    from helpers import mixed_scene_yaml

    from springsim.cli import main
    from springsim.run.driver import Trajectory

    path = tmp_path / "mixed.yaml"  # converged stages and solves: the runs differ by round-off, not by tolerances
    path.write_text(mixed_scene_yaml(cloths=True).replace("steps: 5,", "steps: 5, force_rtol: 1.0e-10, "
                                                                       "linear_rtol: 1.0e-12,"))
    out = tmp_path / "d.npz"
    mpirun(2, [sys.executable, "-m", "springsim", "run", str(path), "--backend", "petsc", "--out", str(out), "-q"])
    _matches_serial_run(path, out, (6, 78, 3), 1e-6)
    bad = tmp_path / "bad.yaml"
    head, _, tail = path.read_text().rpartition("softening: 0.05")
    bad.write_text(head + "softening: 1.0e-200" + tail)
    r = mpirun(2, [sys.executable, "-m", "springsim", "run", str(bad), "--backend", "petsc"], check=False)
    assert r.returncode == 2
    lines = [x for x in r.stderr.splitlines() if x.startswith("springsim:")]
    assert len(lines) == 1 and re.fullmatch(rf"springsim: error: {re.escape(str(bad))}: gravitational\[12\]\.softening: "
                                            r"is too small: .*", lines[0]), lines
    assert main(["run", str(bad)]) == 2  # the serial message is the same


@needs_petsc
def test_cli_generator_scene_is_generated_per_rank(tmp_path):
    """A YAML scene of one ``benchmark_cloth`` block under ``mpiexec``: rank 0 reads the file without building the
    model and every rank generates its part (the builder's whole-grid method is disabled in the ranks); the frames
    are the serial run's; a bad value of the block is one line naming it as written, exit 2."""
    from springsim.cli import main
    from springsim.run.driver import Trajectory

    scene_path = tmp_path / "cloth.yaml"
    scene_path.write_text("solver: {type: linearized_implicit, timestep: 0.0166667, steps: 4, jacobian: spd, "
                          "linear_rtol: 1.0e-10}\nbenchmark_cloth: {n: 12, ke: 2.0e+3}\n")
    out = tmp_path / "d.npz"
    mpirun(3, "cli_generated", str(scene_path), str(out))
    # no rank had the whole model; its fingerprint, hashed in bands of rows, is the serial model's
    _matches_serial_run(scene_path, out, (5, 144, 3), 1e-7)
    bad = tmp_path / "bad.yaml"
    for block, message in (("benchmark_cloth: {n: 12, ke: -3}", "benchmark_cloth.ke: must be >= 0, got -3"),
                           # only rank 1's rows overflow: the ranks agree, the particle named as serially
                           ("cloth: {nx: 4, ny: 100, origin: [0, 1.79e+308, 0], spacing: 1.0e+304, pin: none}",
                            "particles[308].pos: must be finite, got [0, inf, 0]")):
        bad.write_text(f"solver: {{type: linearized_implicit, timestep: 0.01}}\n{block}\n")
        r = mpirun(2, [sys.executable, "-m", "springsim", "run", str(bad), "--backend", "petsc"], check=False)
        assert r.returncode == 2
        lines = [x for x in r.stderr.splitlines() if x.startswith("springsim:")]
        assert lines == [f"springsim: error: {bad}: {message}"]
        assert main(["run", str(bad)]) == 2  # the serial message is the same


@needs_petsc
def test_one_rank_failure_ends_every_rank_with_one_message():
    r = mpirun(2, "rank_error", str(ROOT / "scenes" / "cloth_64.yaml"), "1", check=False)
    assert r.returncode != 0
    lines = [x for x in r.stderr.splitlines() if x.startswith("springsim:")]
    assert lines == ["springsim: error: rank 1: RuntimeError: injected failure"]


@needs_petsc
def test_solver_failure_is_raised_on_every_rank_not_used():
    r = mpirun(2, "solver_failure", "cloth", check=False)
    assert r.returncode == 1
    lines = [x for x in r.stderr.splitlines() if x.startswith("springsim:")]
    assert len(lines) == 1 and "SolverError" in lines[0] and "relative residual" in lines[0]


@needs_petsc
def test_mpi_without_petsc_backend_is_refused():
    r = mpirun(2, [sys.executable, "-m", "springsim", "run", str(ROOT / "scenes" / "cloth_64.yaml"), "--steps", "1"],
               check=False)
    assert r.returncode == 2
    assert [x for x in r.stderr.splitlines() if x.startswith("springsim:")] == [
        "springsim: error: 2 MPI processes need --backend petsc (solver.backend: petsc)"]


@needs_petsc
@pytest.mark.parametrize("ranks", [1, 2])
def test_a_system_left_alive_exits_cleanly(ranks):
    """With ``-springsim_sa_smoother gs`` the finest level's sweeps are a Python PC: a program that does not destroy
    its system still exits with status 0 (the contexts are released before PETSc finalises; without that, a
    segmentation fault at exit)."""
    r = mpirun(ranks, "left_alive", "cloth32", check=False)
    assert r.returncode == 0 and r.stdout.count("solved") == ranks, r.stderr
    assert "SEGV" not in r.stderr and "Segmentation" not in r.stderr


@needs_petsc
@pytest.mark.parametrize("ranks", [1, 2])
def test_preconditioner_options_and_reuse(ranks, tmp_path):
    """``-springsim_fine_smoother`` and ``-springsim_pc_reuse`` (springsim.distributed.system.SPRINGSIM_OPTIONS):
    parsing, the finest level's smoother, and a kept preconditioner that goes stale rebuilt fresh (never a wrong
    answer, and no GMRES escalation where a fresh CG + GAMG suffices)."""
    import json

    out = tmp_path / "reuse.json"
    mpirun(ranks, "pc_reuse", "cloth32", str(out))
    r = json.loads(out.read_text())
    assert "-springsim_pc_reuse must be an integer >= 1, got '0'" in r["-springsim_pc_reuse 0"]
    assert "-springsim_pc_reuse must be an integer >= 1, got 'x'" in r["-springsim_pc_reuse x"]
    assert "-springsim_fine_smoother must be sor or gamg, got 'ilu'" in r["-springsim_fine_smoother ilu"]
    assert "-springsim_pc must be sa or gamg, got 'ml'" in r["-springsim_pc ml"]
    assert "-springsim_insertion must be direct or petsc, got 'csr'" in r["-springsim_insertion csr"]
    assert r["fine_default"] == "richardson+sor"
    assert "-springsim_sa_smoother must be sor or gs, got 'ilu'" in r["-springsim_sa_smoother ilu"]
    # springsim's SA: PETSc's SOR on the finest level (first) and the next; with -springsim_sa_smoother gs the finest
    # swept by springsim's compiled block Gauss-Seidel, in the same iterations; the user's smoother when one is
    # chosen; each solves
    assert r["sa_default"]["kinds"] == ["richardson+sor", "richardson+sor"]
    assert r["sa_gs"]["kinds"] == ["richardson+python", "richardson+sor"]
    assert r["sa_user"]["kinds"] == ["richardson+bjacobi", "richardson+bjacobi"]
    assert all(r[k]["ok"] for k in ("sa_default", "sa_gs", "sa_user"))
    assert r["sa_default"]["its"] == r["sa_gs"]["its"]
    first, same, stiff = r["solves_gamg"]
    assert first["builds"] == 1 and first["reuses"] == 0 and first["ok"]
    assert same["builds"] == 1 and same["reuses"] == 1 and same["stale"] == 0 and same["ok"]
    assert stiff["reuses"] == 2 and stiff["stale"] == 1 and stiff["builds"] == 2 and stiff["ok"]
    assert stiff["method"] == "petsc cg+gamg" and stiff["fallback"] is None
    # springsim's levels: kept whole for a matrix of the same coefficients, the coarse operators recomputed for
    # other coefficients (the prolongators kept)
    first, same, stiff = r["solves_sa"]
    assert first["builds"] == 1 and first["reuses"] == 0 and first["ok"]
    assert same["builds"] == 1 and same["reuses"] == 1 and same["stale"] == 0 and same["ok"]
    assert same["coarse_updates"] == 0
    assert stiff["reuses"] == 2 and stiff["ok"] and stiff["method"] == "petsc cg+mg" and stiff["fallback"] is None
    assert stiff["coarse_updates"] == 1
    # kept whole for the same coefficients; stale on the stretched cloth: the coarse operators recomputed from the
    # iterate, and from then on
    built, whole, stretched = r["sa_switch"]
    assert built["builds"] == whole["builds"] == stretched["builds"] == 1
    assert whole["reuses"] == 1 and whole["stale"] == 0 and whole["coarse_updates"] == 0 and whole["whole"]
    assert stretched["stale"] == 1 and stretched["coarse_updates"] == 1 and not stretched["whole"]
    # the finest level's sweeps follow the matrix: read again for each new matrix a kept hierarchy serves whole (the
    # second solve, and the stretched cloth's first attempt before it went stale; the Galerkin update reads it anyway)
    assert (built["sweep_refreshes"], whole["sweep_refreshes"], stretched["sweep_refreshes"]) == (0, 1, 2)
    for s in r["solves_gamg"] + r["solves_sa"] + r["sa_switch"]:
        assert s["ok"] and s["residual"] <= 1.01e-8


@needs_petsc
@pytest.mark.parametrize("ranks", [1, 2, 3])
def test_smoothed_aggregation_levels(ranks, tmp_path):
    """springsim's smoothed aggregation in PCMG (springsim.distributed.sa): the serial set-up's levels on one rank
    (same sizes, the same coarse operator to round-off), rank-local aggregates on several; every coarse operator is
    ``P^T A P`` of the gathered matrices (the rank-by-rank products, the rows sent to their owners and summed), after
    a build and after the Galerkin recomputation with kept prolongators; the values go straight into and out of
    PETSc's arrays, and through PETSc's calls where that is refused, with the same hierarchy; a rank without
    aggregates takes part in the products; CG solves a perturbed cloth and a straight rope (zero prolongator columns, given unit diagonals) to the tolerance; an indefinite
    matrix is never a silent wrong answer."""
    import json

    out = tmp_path / "sa.json"
    mpirun(ranks, "sa_levels", str(out))
    r = json.loads(out.read_text())
    for case in ("cloth", "rope"):
        assert r[case]["ok"] and r[case]["method"] == "petsc cg+mg" and r[case]["residual"] <= 1.01e-8
    assert r["cloth"]["its"] <= 15 and r["rope"]["its"] <= 10
    assert r["cloth_levels"][0] == 720 and len(r["cloth_levels"]) >= 2
    if ranks == 1:
        assert r["serial_levels"] == r["cloth_levels"]
        assert r["coarse_diff"] < 1e-12
    assert r["build_diff"] < 1e-12 and r["galerkin_diff"] < 1e-12
    assert r["direct"]["read"] and all(r["direct"]["write"])
    assert not r["baij"]["read"] and r["baij"]["diff"] < 1e-12  # a BAIJ matrix's values read by rows
    assert r["rope"]["dead"] > 0  # collinear aggregates: the rotation about the rope has no column
    pc = r["petsc_calls"]  # no direct access to PETSc's arrays: the same hierarchy and iterations
    assert pc["ok"] and pc["levels"] == r["cloth_levels"] and pc["its"] == r["cloth"]["its"]
    assert not pc["read"] and not pc["write"]
    assert pc["diff"] < 1e-12 and pc["build_diff"] < 1e-12 and pc["galerkin_diff"] < 1e-12
    er = r["empty_rank"]  # a rank without aggregates (on several ranks): its rows take part all the same
    assert er["levels"] >= 2 and er["coarse_updates"] >= 1
    assert all(x["ok"] and x["method"] == "petsc cg+mg" and x["residual"] <= 1.01e-8 for x in er["runs"])
    if ranks > 1:
        assert er["fewest_aggregates"] == 0
    ind = r["indefinite"]
    assert (ind["ok"] and ind["residual"] <= 1.01e-8) or (not ind["ok"] and ind["failure"])


@needs_petsc
def test_make_distributed_takes_the_linear_solve_group(tmp_path):
    """``make_distributed(linear=LinearSolveOptions(...))``: the group's tolerance is the KSP's; a linear solver name
    (the backend solves with PETSc's KSP) and a tolerance given twice with different values are refused."""
    import json

    out = tmp_path / "linear.json"
    mpirun(2, "linear_group", "cloth", str(out))
    r = json.loads(out.read_text())
    assert r["rtol"] == 1e-9
    assert r["solver"].startswith("linear_solver: the petsc backend solves with PETSc's KSP")
    assert r["twice"].startswith("linear_rtol: given twice")


@needs_petsc
@pytest.mark.slow
def test_distributed_benchmark_runs(tmp_path):
    """``python -m benchmarks distributed`` at a tiny size: its columns, and 1 and 2 ranks agree with the serial
    path to the linear tolerance's effect on the positions."""
    import csv

    from benchmarks import distributed

    _fail()
    assert distributed.main(["--sizes", "10", "--steps", "2", "--ranks", "1", "2", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "distributed.csv", newline="") as fh:
        reader = csv.DictReader(fh)
        rows = list(reader)
    assert reader.fieldnames == distributed.COLUMNS and len(rows) == 3
    assert rows[0]["config"].startswith("serial") and float(rows[0]["diff_to_serial_m"]) == 0.0
    for r in rows[1:]:
        assert r["config"].startswith("petsc") and int(r["failed_steps"]) == 0 and float(r["linear_its"]) > 0
        assert float(r["diff_to_serial_m"]) < 1e-6 and float(r["max_rss_mb"]) > 0 and float(r["step_s"]) > 0


@needs_petsc
@pytest.mark.slow
def test_scene_read_benchmark_runs(tmp_path):
    """``python -m benchmarks scene-read`` at a tiny size: both ways on 1 and 2 ranks, every rank's fingerprint the
    serial model's."""
    import csv

    from benchmarks import scene_read

    _fail()
    assert scene_read.main(["--n", "6", "--ranks", "1", "2", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "scene_read.csv", newline="") as fh:
        reader = csv.DictReader(fh)
        rows = list(reader)
    assert reader.fieldnames == scene_read.COLUMNS and len(rows) == 4
    assert [(r["mode"], r["ranks"]) for r in rows] == [("whole", "1"), ("pieces", "1"), ("whole", "2"), ("pieces", "2")]
    assert all(r["fingerprint_ok"] == "True" and int(r["particles"]) == 36 and int(r["springs"]) == 60 for r in rows)


@needs_petsc
@pytest.mark.slow
def test_distributed_benchmark_weak_scaling(tmp_path):
    """``--weak P``: P^2 particles per rank (side round(P sqrt(ranks))), per-step iterations, memory and the
    communication counted from the scatter and measured by PETSc's log; 1 rank moves nothing."""
    import csv
    import json

    from benchmarks import distributed

    _fail()
    assert distributed.weak_side(256, 1) == 256 and distributed.weak_side(256, 2) == 362
    assert distributed.weak_side(256, 4) == 512 and distributed.weak_side(724, 2) == 1024
    assert distributed.main(["--weak", "8", "--ranks", "1", "2", "--steps", "1", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "distributed_weak.csv", newline="") as fh:
        reader = csv.DictReader(fh)
        rows = list(reader)
    assert reader.fieldnames == distributed.WEAK_COLUMNS and len(rows) == 2
    one, two = rows
    assert [int(r["side"]) for r in rows] == [8, 11] and float(two["particles_per_rank"]) == 60.5
    assert float(one["efficiency"]) == 1.0 and float(two["efficiency"]) > 0
    for r in rows:
        assert int(r["failed_steps"]) == 0 and float(r["newton_its"]) >= 1 and float(r["linear_its"]) > 0
        assert float(r["max_rss_mb"]) >= float(r["mean_rss_mb"]) > 0
        assert float(r["step_s_max"]) > 0 and float(r["cpu_step_s_max"]) > 0
    for k in ("ghosts", "ghost_mb", "offproc_blocks", "offproc_mb", "scatter_mb", "assembly_mb"):
        assert float(one[k]) == 0 and float(two[k]) > 0, k
    # the cloth's bands: the lower rank's ghosts are the upper rank's first two rows (bending reaches two rows)
    assert int(two["ghosts"]) == 2 * 11
    # the scatters PETSc logs carry at least the ghost exchanges counted from their sizes
    assert float(two["scatter_mb"]) >= float(two["ghost_mb"])
    saved = json.loads((tmp_path / "distributed_weak.json").read_text())
    assert [r["ranks"] for r in saved["rows"]] == [1, 2] and "nproc" in saved["machine"]


# -- options (no PETSc needed) -----------------------------------------------------------------------------------
def test_backend_option_is_validated(tmp_path, capsys):
    from springsim.cli import main

    cloth = str(ROOT / "scenes" / "cloth_64.yaml")
    assert main(["run", cloth, "--backend", "nosuch"]) == 2
    assert "argument --backend: invalid choice: 'nosuch'" in capsys.readouterr().err
    bad = tmp_path / "b.yaml"
    bad.write_text("solver: {type: linearized_implicit, timestep: 0.01, backend: mpi}\nbenchmark_cloth: {n: 4}\n")
    assert main(["run", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"springsim: error: {bad}: solver.backend: unknown backend 'mpi'; choose one of serial, petsc"]


def test_petsc_options_without_the_backend_are_reported_unused(capsys):
    from springsim.cli import main

    assert main(["run", str(ROOT / "scenes" / "cloth_64.yaml"), "--steps", "1", "--petsc-options", "-ksp_rtol 1",
                 "-q"]) == 0
    assert "does not use petsc_options" in capsys.readouterr().err


def test_petsc_backend_without_petsc_is_one_line(capsys, monkeypatch):
    """Where petsc4py or mpi4py cannot be imported (simulated here, so the test runs everywhere)."""
    import springsim.distributed as dist
    from springsim.cli import main
    from springsim.distributed._petsc import INSTALL_HINT, BackendUnavailable

    def unavailable():
        raise BackendUnavailable(f"{INSTALL_HINT} (No module named 'petsc4py')")

    monkeypatch.setattr(dist, "import_petsc", unavailable)

    assert main(["run", str(ROOT / "scenes" / "cloth_64.yaml"), "--backend", "petsc", "--steps", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("springsim: error: the petsc backend needs petsc4py and mpi4py")
    assert "docs/distributed.md" in err[0]


def test_petsc_options_yaml_mapping_or_string():
    from springsim.errors import SceneError
    from springsim.scene import load_scene

    base = "particles: [{pos: [0, 0, 0], mass: 1}]\nsolver: {type: linearized_implicit, timestep: 0.01, backend: petsc, "
    cfg = load_scene(base + "petsc_options: {ksp_type: gmres, pc_gamg_threshold: 0.02}}").config
    assert cfg.backend == "petsc" and cfg.petsc_options == {"ksp_type": "gmres", "pc_gamg_threshold": 0.02}
    assert load_scene(base + "petsc_options: '-ksp_type gmres'}").config.petsc_options == "-ksp_type gmres"
    with pytest.raises(SceneError, match=r"solver.petsc_options.ksp_type: must be a string, number or boolean"):
        load_scene(base + "petsc_options: {ksp_type: [1, 2]}}")
    with pytest.raises(SceneError, match=r"solver.petsc_options: must be a string or a mapping, got list"):
        load_scene(base + "petsc_options: [1]}")


@pytest.mark.parametrize("size", [2, 3])
def test_partition_follows_a_given_order(size):
    """With a renumbering (a graph partition's), rank blocks are blocks of that order; pairs and forces still
    split exactly once."""
    from springsim.distributed.partition import system_order

    model = scene("shuffled_cloth")
    order = np.random.default_rng(1).permutation(model.free_count)
    offsets = np.array([0, 40] + [model.free_count] * (size - 1))
    parts = [partition(model, size, r, offsets=offsets, order=order) for r in range(size)]
    assert np.array_equal(np.concatenate([p.local_particles[:p.n_own] for p in parts]), system_order(model, order))
    _check_summed_forces(model, parts)
    with pytest.raises(ValueError, match="permutation"):
        partition(model, size, 0, order=np.zeros(model.free_count, dtype=int))
    with pytest.raises(ValueError, match="offsets"):
        partition(model, size, 0, offsets=np.zeros(size + 1, dtype=int))


def test_partitioner_option(capsys):
    from springsim.cli import main

    cloth = str(ROOT / "scenes" / "cloth_64.yaml")
    assert main(["run", cloth, "--partitioner", "metis"]) == 2
    assert "argument --partitioner: invalid choice: 'metis'" in capsys.readouterr().err
    assert main(["run", cloth, "--steps", "1", "--partitioner", "ptscotch", "-q"]) == 0
    assert "does not use partitioner" in capsys.readouterr().err


# -- scenes built per rank, frames streamed ---------------------------------------------------------------------------
PINS = ["edge", "ends", "none", ["left", {"box": [[0.0, 0.0, 0.0], [0.5, 0.25, 0.0]]}], {"i": 3, "j": 4}]


@pytest.mark.parametrize("pin", PINS)
@pytest.mark.parametrize("size", [1, 2, 3, 5])
def test_cloth_built_per_rank_is_the_models_part(pin, size):
    """A rank's generated rows of the cloth are its part of the whole model, to the last bit: the same particles,
    ghosts, owned springs (same order and values), per-particle data and block of the fixed particles."""
    from springsim.distributed import benchmark_cloth_part, model_part
    from springsim.scene import benchmark_cloth

    model = benchmark_cloth(9, kd=0.2, pin=pin)
    for rank in range(size):
        a, b = benchmark_cloth_part(9, size, rank, kd=0.2, pin=pin), model_part(model, size, rank)
        pa, pb = a.part, b.part
        assert (pa.n_own, pa.n_ghost) == (pb.n_own, pb.n_ghost)
        assert np.array_equal(pa.local_particles, pb.local_particles)
        assert np.array_equal(pa.local_to_free, pb.local_to_free)
        assert pa.pair_model.fingerprint() == pb.pair_model.fingerprint()
        assert pa.particle_model.fingerprint() == pb.particle_model.fingerprint()
        assert a.fixed_model.fingerprint() == b.fixed_model.fingerprint()
        assert np.array_equal(a.fixed_ids, b.fixed_ids)
        assert (a.particle_count, a.free_count, a.damped, a.spring_count) == (
            b.particle_count, b.free_count, b.damped, b.spring_count)
    with pytest.raises(Exception, match="cloth.pin"):
        benchmark_cloth_part(9, 2, 0, pin="topp")


def test_frame_spool_writes_a_trajectory_atomically(tmp_path):
    """Frames streamed to a FrameSpool make the file Trajectory.save would; the target is untouched until the end,
    and no temporary file is left."""
    from springsim.io._spool import FrameSpool
    from springsim.run.driver import Trajectory

    target = tmp_path / "frames.npz"
    target.write_bytes(b"old")
    q = np.random.default_rng(1).standard_normal((3, 5, 3))
    spool = FrameSpool(target)
    for k in range(3):
        spool.append(q[k], 2 * q[k])
    assert target.read_bytes() == b"old"
    with pytest.raises(ValueError):
        spool.append(np.zeros((4, 3)), np.zeros((4, 3)))
    spool.finish(np.arange(3.0), {"format": "springsim-trajectory", "format_version": 1, "x": 1})
    spool.discard()
    t = Trajectory.load(target)
    assert np.array_equal(t.q, q) and np.array_equal(t.qd, 2 * q) and t.meta["x"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames.npz"]
    spool = FrameSpool(target)
    spool.append(q[0], q[0])
    spool.discard()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames.npz"] and Trajectory.load(target).frame_count == 3


@needs_petsc
@pytest.mark.parametrize("kind, integrator, ranks, partitioner",
                         [("cloth", "linearized_implicit", 1, "contiguous"),
                          ("cloth", "implicit_euler", 2, "contiguous"),
                          ("cloth", "linearized_implicit", 3, "contiguous"),
                          ("cloth", "symplectic_euler", 2, "ptscotch"),
                          ("scattered", "implicit_euler", 2, "contiguous"),
                          ("scattered", "bdf2", 3, "ptscotch")])
def test_scene_built_per_rank_matches_the_replicated_run(kind, integrator, ranks, partitioner, tmp_path):
    """A generated cloth (each rank its rows) or a scene scattered from rank 0, run with the frames streamed to a
    file: the frames are the replicated model's to round-off (the parts are the same to the last bit,
    test_cloth_built_per_rank_is_the_models_part; PETSc's assembly adds the ghost rows in the order their messages
    arrive, and a graph partition sums in another order), and the fingerprint is the whole model's."""
    from springsim.run.driver import Trajectory

    out = tmp_path / "t.npz"
    mpirun(ranks, "built_per_rank", kind, integrator, "4", str(out), partitioner)
    t, ref = Trajectory.load(out), np.load(str(out) + ".ref.npz")
    assert t.q.shape == ref["q"].shape and t.frame_count == 5
    assert np.abs(t.q - ref["q"]).max() <= 1e-10 and np.abs(t.qd - ref["qd"]).max() <= 1e-7
    assert int(ref["ranks"]) == ranks
    assert t.meta["model_fingerprint"] == str(ref["fingerprint"])  # a generated part's hashed in bands of rows
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.npz", "t.npz.ref.npz"]  # no temporary file left


@needs_petsc
def test_stopped_run_streams_its_frames(tmp_path):
    """A blow-up with frames streamed: every rank stops at the same step, the file holds the finite frames so far."""
    from springsim.run.driver import Trajectory

    out = tmp_path / "s.npz"
    r = mpirun(2, "stopped_streamed", str(out))
    steps = set(re.findall(r"stopped at step (\d+)", r.stdout))
    assert len(steps) == 1 and r.stdout.count("stopped at step") == 2
    t = Trajectory.load(out)
    assert t.frame_count == int(steps.pop()) and np.isfinite(t.q).all()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.npz"]


@needs_petsc
@pytest.mark.parametrize("rank, signame", [(1, "SIGTERM"), (0, "SIGINT")])
def test_cli_interrupt_on_one_rank_stops_every_rank_and_saves(rank, signame, tmp_path):
    """SIGTERM or Ctrl-C reaching one rank only, in the middle of a step: the ranks agree after the step
    (springsim.run.interrupts), every rank stops there, rank 0 saves the streamed frames so far (the other ranks
    wait for it) and says so, and every rank's status is the signal's (128 + it)."""
    from springsim.run.driver import Trajectory

    scene_path = tmp_path / "cloth.yaml"
    scene_path.write_text("solver: {type: implicit_euler, timestep: 0.0166667, steps: 40}\nbenchmark_cloth: {n: 8}\n")
    out = tmp_path / "i.npz"
    r = mpirun(2, "signalled_cli", str(rank), signame, str(scene_path), str(out))
    code = {"SIGTERM": 143, "SIGINT": 130}[signame]
    assert sorted(re.findall(r"rank (\d): status (\d+)", r.stdout)) == [("0", str(code)), ("1", str(code))]
    word = {"SIGTERM": "terminated", "SIGINT": "interrupted"}[signame]
    assert f"springsim: {word}: interrupted after step 3 of 40" in r.stderr
    assert r.stderr.count("interrupted after") == 1
    t = Trajectory.load(out)
    assert t.frame_count == 4 and np.isclose(t.t[-1], 3 * 0.0166667)  # every step up to the interrupted one
    assert np.isfinite(t.q).all()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cloth.yaml", "i.npz"]  # no spool left


@needs_petsc
def test_graph_partition_weighs_particles_by_their_pairs(tmp_path):
    """On the distributed graph, PT-Scotch balances the parts' pairs (each particle weighted by its pair count,
    through MatPartitioningSetVertexWeights), not their particle counts."""
    import json

    out = tmp_path / "w.json"
    mpirun(2, "weighted_partition", str(out))
    r = json.loads(out.read_text())
    (n0, e0), (n1, e1) = r["False"], r["True"]
    assert max(n0) <= 1.1 * min(n0) and max(e0) > 2 * min(e0)   # unweighted: particles balanced, pairs not
    assert max(e1) <= 1.1 * min(e1) and max(n1) > 1.5 * min(n1)  # weighted: pairs balanced
