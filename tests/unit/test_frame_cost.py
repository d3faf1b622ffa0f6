"""benchmarks/frame_cost.py at a tiny size: it runs, writes its columns, and the explicit limit is verified."""

from __future__ import annotations

import argparse
import csv
import importlib
import math

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # the benchmarks at tiny sizes



@pytest.fixture(scope="module")
def fc():
    yield importlib.import_module("benchmarks.frame_cost")


def _read(path):
    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    return rows, list(rows[0].keys()) if rows else []


def test_quick_run_writes_columns_and_verifies_the_limit(fc, tmp_path):
    assert fc.main(["--quick", "--out", str(tmp_path)]) == 0
    rows, cols = _read(tmp_path / "frame_cost.csv")
    assert cols == fc.COLUMNS and len(rows) == 1
    r = rows[0]
    assert int(r["n"]) == 6 and int(r["dofs"]) == 3 * 6 * 5
    assert r["status"] == "ok" and float(r["err_rms"]) < 0.01 and float(r["wall_per_frame_s"]) > 0
    # the explicit count is the one computed from omega, verified stable; 0.7x of it is not
    S = int(r["se_substeps"])
    assert S == int(r["substeps_computed"]) == fc.explicit_substeps(float(r["omega_max"]))
    assert r["se_stable"] == "True" and r["se_lower_unstable"] == "True"
    assert int(r["se_lower_substeps"]) == math.floor(0.7 * S) < S
    assert float(r["omega_max"]) <= float(r["omega_gershgorin"]) * (1 + 1e-12)
    cand, ccols = _read(tmp_path / "frame_cost_candidates.csv")
    assert ccols == fc.CANDIDATE_COLUMNS
    assert {c["role"] for c in cand} == {"candidate", "reference"}
    assert any(c["status"] == "ok, below target" for c in cand)
    assert "| n | dofs | config |" in (tmp_path / "frame_cost.md").read_text()


def test_omega_max_matches_dense_eigenvalue(fc):
    """Lanczos on the sparse assembled K agrees with a dense eigen-solve of M^-1 K (small cloth), deformed too."""
    from springsim.assembly import SystemAssembler
    from springsim.forces import dense_jacobians, make_force_terms

    model = fc.cloth(5)
    terms = make_force_terms(model)
    asm = SystemAssembler(model, terms)
    q = model.particle_q + 0.02 * np.random.default_rng(1).standard_normal(model.particle_q.shape)
    for pos in (model.particle_q, q):
        got = fc.omega_max(asm, pos, tol=1e-12)
        dfdq, _ = dense_jacobians(terms, pos, np.zeros_like(pos))
        free = (3 * model.free_particles[:, None] + np.arange(3)).ravel()
        m = np.repeat(model.particle_mass[model.free_particles], 3)
        S = -dfdq[np.ix_(free, free)] / np.sqrt(np.outer(m, m))
        want = math.sqrt(np.linalg.eigvalsh(0.5 * (S + S.T))[-1])
        assert got["omega"] == pytest.approx(want, rel=1e-8)
        assert got["gershgorin"] >= want


def test_symplectic_euler_limit_is_sharp(fc):
    """At the computed count the run stays bounded; one substep fewer blows up (n = 8)."""
    from springsim.assembly import SystemAssembler
    from springsim.forces import make_force_terms

    model = fc.cloth(8)
    om = fc.omega_max(SystemAssembler(model, make_force_terms(model)), model.particle_q)["omega"]
    S = fc.explicit_substeps(om)
    assert fc.FRAME_DT / S < 2.0 / om <= fc.FRAME_DT / (S - 1)
    assert fc.run_symplectic(model, S, window=0.05)["stable"]
    bad = fc.run_symplectic(model, S - 1, window=0.05)
    assert not bad["stable"] and bad["detected_at_s"] <= 0.05


@pytest.mark.parametrize("text", ["tr_bdf2:240", "symplectic_euler:60:auto", "tr_bdf2:-1:auto", "tr_bdf2:x:auto",
                                  "tr_bdf2:60:nosuch"])
def test_candidate_errors_name_the_field(fc, text):
    with pytest.raises(argparse.ArgumentTypeError, match="^--candidates: "):
        fc.parse_candidate(text)


def test_parse_candidate(fc):
    c = fc.parse_candidate("tr_bdf2:240:amg-cg")
    assert (c.method, c.h, c.solver) == ("tr_bdf2", 1 / 240, "amg-cg") and c.label == "tr_bdf2 h=1/240 amg-cg"
