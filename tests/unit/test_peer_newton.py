"""The peer benchmark (benchmarks/peer_newton.py): NVIDIA Newton's model of a springsim cloth is the same system.

Needs the ``peer`` extra (warp-lang, newton); without it only the exit-status test runs.
"""

from __future__ import annotations

import csv

import numpy as np
import pytest

from benchmarks import peer_newton
from springsim.scene import benchmark_cloth


def test_without_the_peer_the_benchmark_exits_2(monkeypatch, capsys, tmp_path):
    """No canned figures: when newton does not import, one line on stderr and status 2, nothing written."""
    def missing():
        raise peer_newton.PeerUnavailable("NVIDIA Newton is not importable (test)")

    monkeypatch.setattr(peer_newton, "import_peer", missing)
    assert peer_newton.main(["--quick", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not importable" in err[0]
    assert not (tmp_path / "peer_newton.csv").exists()


@pytest.fixture(scope="module")
def peer():
    pytest.importorskip("warp")
    pytest.importorskip("newton")
    return peer_newton.import_peer()


@pytest.mark.parametrize("kd", [0.0, 2.0])
def test_newton_model_follows_springsim(peer, kd):
    """Both engines from a perturbed rest state for 40 substeps: the same motion to float32 round-off.

    Damped springs too (kd = 2 N s/m): both define the damping force as ``-b (n . v) n``.
    """
    model = benchmark_cloth(8, damping=kd)
    sp, nt = peer_newton.SpringsimEngine(model), peer_newton.NewtonEngine(model)
    assert nt.model.particle_count == model.particle_count and nt.model.spring_count == model.spring_count
    np.testing.assert_allclose(nt.model.spring_rest_length.numpy(), model.spring_rest_length, rtol=1e-6)
    q0 = model.particle_q.copy()
    free = model.free_particles
    q0[free] += 1e-3 * np.random.default_rng(1).standard_normal((free.size, 3))
    for eng in (sp, nt):
        eng.set_state(q0, model.particle_qd)
        eng.advance(40, 1.0 / 60 / 40)  # one frame, 40 substeps (the 8 x 8 cloth's limit is about 20)
    (q_sp, _), (q_nt, _) = sp.state(), nt.state()
    size = 1.0  # the cloth is 1 m
    moved = np.max(np.linalg.norm(q_sp - q0, axis=1))
    assert moved > 1e-3  # it fell: the comparison is not of two resting states
    assert np.max(np.linalg.norm(q_nt - q_sp, axis=1)) < 1e-4 * size
    fixed = model.particle_fixed
    assert np.array_equal(q_nt[fixed], q0[fixed].astype(np.float32).astype(np.float64))


def test_simulate_engine_is_the_raw_loop():
    """The public-path engine (one ``simulate`` call per frame) steps the same states as the raw loop."""
    model = benchmark_cloth(6)
    raw, pub = peer_newton.SpringsimEngine(model), peer_newton.SimulateEngine(model)
    for eng in (raw, pub):
        eng.advance(30, 1.0 / 60 / 30)
    np.testing.assert_allclose(pub.state()[0], raw.state()[0], rtol=0, atol=1e-12)


def test_shared_stability_criterion(peer):
    """The bisection finds a count stable for both engines with the one below it unstable."""
    model = benchmark_cloth(6)
    crit = dict(window=0.05, max_steps=400)
    for eng in (peer_newton.SpringsimEngine(model), peer_newton.NewtonEngine(model)):
        s = peer_newton.smallest_stable(eng, model, 8, **crit)
        assert peer_newton.stable(eng, model, s, **crit) and not peer_newton.stable(eng, model, s - 1, **crit)


def test_newton_model_refuses_what_newton_lacks(peer):
    """Drag has no counterpart among Newton's particle forces: refused, not dropped."""
    from springsim import ModelBuilder

    b = ModelBuilder()
    b.add_particle((0.0, 0.0, 0.0), mass=1.0, drag=0.5)
    b.add_particle((1.0, 0.0, 0.0), mass=1.0)
    b.add_spring(0, 1, stiffness=10.0)
    with pytest.raises(ValueError, match="drag"):
        peer_newton.newton_model(b.finalize())


@pytest.mark.slow
def test_peer_benchmark_quick(peer, tmp_path, capsys):
    """--quick runs both engines, writes every column (errors against the reference too) and prints the load."""
    assert peer_newton.main(["--quick", "--out", str(tmp_path), "--cache-dir", str(tmp_path / "ref")]) == 0
    with open(tmp_path / "peer_newton.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 1 and list(rows[0]) == peer_newton.COLUMNS
    r = rows[0]
    assert int(r["substeps_equal"]) == max(int(r["substeps_springsim"]), int(r["substeps_newton"]))
    assert float(r["diff_1frame_m"]) < 1e-4 and float(r["ratio"]) > 0 and float(r["ratio_simulate"]) > 0
    # the same motion to round-off, so the same error against the reference to well within it
    assert abs(float(r["err_newton_m"]) - float(r["err_springsim_m"])) < 1e-4 and int(r["ref_frames"]) == 5
    assert "load average" in capsys.readouterr().out
