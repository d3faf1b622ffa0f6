"""Benchmark scripts at tiny sizes: they run, write the expected columns, and the reference is sound."""

from __future__ import annotations

import csv
import importlib
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture(scope="module")
def bench():
    """Import the benchmark modules from ``benchmarks/``."""
    sys.path.insert(0, str(BENCH))
    try:
        yield {name: importlib.import_module(name)
               for name in ("_common", "speed_vs_error", "linear_solve_error", "scaling")}
    finally:
        sys.path.remove(str(BENCH))


def _read(path):
    with open(path) as fh:
        rows = list(csv.DictReader(fh))
        return rows, rows[0].keys() if rows else []


def test_speed_vs_error_quick(bench, tmp_path):
    """--quick writes CSV/markdown with every column, every integrator, and midpoint converges at order ~2."""
    from springsim.integrators import INTEGRATORS

    mod = bench["speed_vs_error"]
    assert mod.main(["--quick", "--out", str(tmp_path)]) == 0
    rows, cols = _read(tmp_path / "speed_vs_error.csv")
    assert list(cols) == mod.COLUMNS
    assert {r["integrator"] for r in rows if r["sweep"] == "dt"} == set(INTEGRATORS)
    assert {"dt", "newton", "solver"} <= {r["sweep"] for r in rows}
    ok = [r for r in rows if r["status"].startswith("ok")]
    assert ok and all(np.isfinite(float(r["err_rms"])) for r in ok)
    orders, ocols = _read(tmp_path / "convergence_orders.csv")
    assert list(ocols) == mod.ORDER_COLUMNS
    mid = [o for o in orders if o["case"] == "spring" and o["integrator"] == "midpoint"]
    assert 1.6 < float(mid[0]["order"]) < 2.4
    assert "| case |" in (tmp_path / "speed_vs_error.md").read_text()
    assert (tmp_path / "pareto_spring.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_linear_solve_error_quick(bench, tmp_path):
    """--quick solves the n = 8 step systems with every solver and mode; direct has zero error."""
    from springsim.forces import JACOBIAN_MODES
    from springsim.linsolve import LINEAR_SOLVERS

    mod = bench["linear_solve_error"]
    assert mod.main(["--quick", "--out", str(tmp_path)]) == 0
    rows, cols = _read(tmp_path / "linear_solve_error.csv")
    assert list(cols) == mod.COLUMNS
    assert {r["solver"] for r in rows} == set(LINEAR_SOLVERS)
    assert {r["jacobian"] for r in rows} == set(JACOBIAN_MODES)
    direct = [r for r in rows if r["solver"] == "direct"]
    assert all(float(r["rel_error"]) == 0.0 for r in direct)
    tight = [r for r in rows if r["rtol"] and float(r["rtol"]) <= 1e-8 and r["status"].startswith("ok")]
    assert tight and all(float(r["rel_error"]) < 1e-5 for r in tight)


def test_scaling_quick(bench, tmp_path):
    """--quick times two sizes and fits a finite exponent."""
    mod = bench["scaling"]
    assert mod.main(["--quick", "--out", str(tmp_path)]) == 0
    rows, cols = _read(tmp_path / "scaling.csv")
    assert list(cols) == mod.COLUMNS
    assert [int(r["n"]) for r in rows] == [8, 16]
    assert all(float(r["step_s"]) > 0 for r in rows)
    assert "DOFs^" in (tmp_path / "scaling.md").read_text()


def test_reference_agrees_with_springsim_at_tiny_steps(bench):
    """The solve_ivp reference and TR-BDF2/midpoint at h = 1/4000 s agree on the spring and a 4x4 cloth."""
    from springsim.driver import simulate
    from springsim.integrators import INTEGRATORS, make_integrator

    c = bench["_common"]
    name = "tr_bdf2" if "tr_bdf2" in INTEGRATORS else "midpoint"
    for case in (c.scene_case("spring", 0.1), c.benchmark_case(4, 0.1)):
        q_ref, _, _, _ = c.reference_final(case, method="Radau", cache=False)
        tr = simulate(case.model, make_integrator(name, case.model, newton_tol=1e-10, newton_maxiter=10),
                      1 / 4000, 400, record=False)
        rms, mx = c.position_errors(tr.q[-1], q_ref, case.size)
        assert mx < 1e-5, (case.name, mx)


def test_reference_methods_agree(bench):
    """Radau (sparse Jacobian) and DOP853 references agree on the 4x4 cloth to 1e-9 of its size."""
    c = bench["_common"]
    case = c.benchmark_case(4, 0.1)
    qa = c.reference_final(case, method="Radau", cache=False)[0]
    qb = c.reference_final(case, method="DOP853", cache=False)[0]
    assert c.position_errors(qa, qb, case.size)[1] < 1e-9


def test_common_helpers(bench):
    """fit_order recovers a known slope; position_errors is relative and inf for blow-ups; tables render."""
    c = bench["_common"]
    dts = np.array([1 / 60, 1 / 120, 1 / 240, 1 / 480])
    assert c.fit_order(dts, 3.0 * dts**2) == pytest.approx(2.0)
    rng = np.random.default_rng(7)
    q = rng.standard_normal((5, 3))
    d = np.zeros((5, 3))
    d[:, 0] = 0.2
    assert c.position_errors(q + d, q, 2.0) == pytest.approx((0.1, 0.1))
    assert c.position_errors(np.full((5, 3), np.inf), q, 1.0)[0] == np.inf
    md = c.markdown_table([{"a": 1.23456, "b": "x"}], ["a", "b"])
    assert md.splitlines()[2] == "| 1.23 | x |"
    info = c.machine_info()
    assert {"cpu", "nproc", "ram", "python", "numpy", "scipy", "pyamg"} <= set(info)


def test_scene_cases_build(bench):
    """The shipped-scene cases build models with a positive size."""
    c = bench["_common"]
    for case in c.scene_cases(0.5):
        assert case.model.particle_count >= 2 and case.size > 0
