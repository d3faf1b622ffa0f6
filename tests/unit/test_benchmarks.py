"""Benchmark scripts at tiny sizes: they run, write the expected columns, and the reference is sound."""

from __future__ import annotations

import csv
import math
import importlib

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # the benchmarks at tiny sizes



@pytest.fixture(scope="module")
def bench():
    """Import the benchmark modules from ``benchmarks/``."""
    return {name: importlib.import_module(f"benchmarks.{name}")
            for name in ("common", "speed_vs_error", "linear_solve_error", "scaling")}


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
    assert {r["sweep"] for r in rows} == set(mod.ALL_SWEEPS)
    adaptive = [r for r in rows if r["sweep"] == "adaptive"]
    assert {r["method"] for r in adaptive} == {f"{n} adaptive" for n in mod.ADAPTIVE_INTEGRATORS}
    for r in adaptive:
        assert r["status"].startswith("ok"), r
        assert float(r["time_rtol"]) > 0 and int(float(r["steps"])) >= 1 and int(float(r["rejected"])) >= 0
        assert 0 < float(r["h_min"]) <= float(r["dt"]) <= float(r["h_max"])
    ok = [r for r in rows if r["status"].startswith("ok")]
    assert ok and all(np.isfinite(float(r["err_rms"])) for r in ok)
    orders, ocols = _read(tmp_path / "convergence_orders.csv")
    assert list(ocols) == mod.ORDER_COLUMNS
    mid = [o for o in orders if o["case"] == "spring" and o["integrator"] == "midpoint"]
    assert 1.6 < float(mid[0]["order"]) < 2.4
    assert "| case |" in (tmp_path / "speed_vs_error.md").read_text()
    assert (tmp_path / "pareto_spring.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # --from-csv re-tabulates the same rows (statuses re-derived) without running anything
    again = tmp_path / "again"
    assert mod.main(["--from-csv", str(tmp_path / "speed_vs_error.csv"), "--out", str(again)]) == 0
    rows2, _ = _read(again / "speed_vs_error.csv")
    assert [(r["method"], r["status"]) for r in rows2] == [(r["method"], r["status"]) for r in rows]


def test_speed_vs_error_adaptive_sweep(bench):
    """The adaptive sweep on the spring over 0.5 s: a tighter time tolerance gives smaller steps and a smaller error."""
    mod, c = bench["speed_vs_error"], bench["common"]
    case = c.scene_case("spring", 0.5)
    rows = mod.run_case(case, dts=[], newton_tols=[], solver_rtols=[], time_rtols=[1e-2, 1e-5], sweeps=("adaptive",),
                        log=lambda msg: None)
    assert [(r["integrator"], r["time_rtol"]) for r in rows] == [
        (n, tol) for n in mod.ADAPTIVE_INTEGRATORS for tol in (1e-2, 1e-5)]
    assert set(rows[0]) <= set(mod.COLUMNS)
    for name in mod.ADAPTIVE_INTEGRATORS:
        loose, tight = (r for r in rows if r["integrator"] == name)
        assert loose["status"] == tight["status"] == "ok"
        assert tight["err_rms"] < 0.2 * loose["err_rms"], (name, loose["err_rms"], tight["err_rms"])
        assert tight["dt"] < loose["dt"] and tight["steps"] > loose["steps"]
        assert tight["newton_per_step"] >= 1


def test_speed_vs_error_default_bounds(bench):
    """The bounded default run keeps every sweep's essentials on every case: h = 1/30 ... >= 1/120, adaptive."""
    mod, c = bench["speed_vs_error"], bench["common"]
    cases = c.scene_cases(0.5) + [c.benchmark_case(n, 0.5) for n in (8, 16, 32)]
    for case in cases:
        b = mod.default_bounds(case)
        assert b["min_dt"] <= 1 / 120 and {"dt", "adaptive"} <= set(b["sweeps"]) <= set(mod.ALL_SWEEPS)
        assert b["time_rtols"] and all(0 < t < 1 for t in b["time_rtols"])
    with pytest.raises(ValueError, match="sweeps"):
        mod.run_case(cases[0], dts=[], newton_tols=[], solver_rtols=[], sweeps=("nope",))


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
    # --append keeps those rows and adds a run restricted to one mode
    assert mod.main(["--quick", "--out", str(tmp_path), "--append", "--modes", "spd"]) == 0
    rows2, _ = _read(tmp_path / "linear_solve_error.csv")
    assert rows2[:len(rows)] == rows
    assert len(rows2) > len(rows) and {r["jacobian"] for r in rows2[len(rows):]} == {"spd"}


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
    from springsim.integrators import INTEGRATORS, make_integrator
    from springsim.run.driver import simulate

    c = bench["common"]
    name = "tr_bdf2" if "tr_bdf2" in INTEGRATORS else "midpoint"
    for case in (c.scene_case("spring", 0.1), c.benchmark_case(4, 0.1)):
        q_ref, _, _, _ = c.reference_final(case, method="Radau", cache=False)
        tr = simulate(case.model, make_integrator(name, case.model, force_rtol=1e-10, newton_maxiter=10),
                      1 / 4000, 400, record=False)
        rms, mx = c.position_errors(tr.q[-1], q_ref, case.size)
        assert mx < 1e-5, (case.name, mx)


def test_reference_methods_agree(bench):
    """Radau (sparse Jacobian) and DOP853 references agree on the 4x4 cloth to 1e-9 of its size."""
    c = bench["common"]
    case = c.benchmark_case(4, 0.1)
    qa = c.reference_final(case, method="Radau", cache=False)[0]
    qb = c.reference_final(case, method="DOP853", cache=False)[0]
    assert c.position_errors(qa, qb, case.size)[1] < 1e-9


def test_common_helpers(bench):
    """fit_order recovers a known slope; position_errors is relative and inf for blow-ups; tables render."""
    c = bench["common"]
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
    c = bench["common"]
    for case in c.scene_cases(0.5):
        assert case.model.particle_count >= 2 and case.size > 0


def test_blas_threads_benchmark_tiny(capsys):
    """benchmarks/blas_threads.py at a tiny size prints its table; both policies give the same trajectory; the policy
    is restored afterwards."""
    pytest.importorskip("threadpoolctl")
    from springsim._runtime import threads as _threads

    mod = importlib.import_module("benchmarks.blas_threads")
    policy = _threads.single_blas_thread
    assert mod.main(["--n", "4", "--steps", "2", "--solver", "direct"]) == 0
    row = capsys.readouterr().out.strip().splitlines()[-1].split("|")
    assert float(row[-2]) <= 1e-12 and _threads.single_blas_thread is policy


def test_one_entry_point(capsys):
    """``python -m benchmarks`` lists every benchmark; an unknown name is one line and exit 2; a name runs it."""
    from benchmarks import BENCHMARKS
    from benchmarks.__main__ import main

    assert main([]) == 0
    listing = capsys.readouterr().out
    assert all(name in listing for name in BENCHMARKS)
    assert main(["nope"]) == 2 and "unknown benchmark 'nope'" in capsys.readouterr().err
    assert main(["blas-threads", "--n", "3", "--steps", "1", "--solver", "direct"]) == 0


def test_explicit_limit_quick(tmp_path, capsys):
    """explicit-limit at n = 6: a verified limit (stable at it, unstable at 0.7x), a finite window with a small
    energy drift (the undamped cloth conserves energy; symplectic Euler's drift stays bounded), its cost."""
    from benchmarks import explicit_limit

    assert explicit_limit.main(["--quick", "--out", str(tmp_path)]) == 0
    rows, cols = _read(tmp_path / "explicit_limit.csv")
    assert list(cols) == explicit_limit.COLUMNS and len(rows) == 1
    r = rows[0]
    assert int(r["substeps"]) >= int(r["substeps_computed"]) > int(r["lower_substeps"])
    assert r["lower_unstable"] == "True"
    assert r["finite"] == "True" and int(r["frames"]) == 3
    assert 0 < float(r["energy_drift"]) < 0.05 and float(r["cpu_per_frame_s"]) > 0
    assert "| n | ke |" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        explicit_limit.main(["--ke", "-1"])


def test_stiff_regime_quick(tmp_path):
    """``python -m benchmarks stiff-regime --quick``: per target (1 cm, 5 cm) one row per method with its cheapest
    configuration within it, the ratio to symplectic Euler at its verified limit, no failed step, and the plot."""
    from benchmarks import stiff_regime as sr

    assert sr.main(["--quick", "--out", str(tmp_path)]) == 0
    rows, cols = _read(tmp_path / "stiff_regime.csv")
    assert list(cols) == sr.COLUMNS
    methods = {"symplectic_euler", "implicit_euler", "tr_bdf2", "linearized_implicit"}
    assert {(float(r["target"]), r["method"]) for r in rows} == {(t, m) for t in sr.TARGETS for m in methods}
    se = {float(r["target"]): r for r in rows if r["method"] == "symplectic_euler"}
    for r in rows:
        assert int(r["n"]) == 6 and float(r["ke"]) == 1e6 and int(r["frames"]) == 5
        assert (r["reached"] == "True") == (float(r["err_rms"]) < float(r["target"]))
        assert float(r["ratio_to_se"]) == pytest.approx(float(r["cpu_per_frame_s"]) /
                                                        float(se[float(r["target"])]["cpu_per_frame_s"]))
        assert float(r["floor"]) < 1e-6 and r["decidable"] == "True" and r["load_start"]
        if r["method"] != "symplectic_euler":
            assert int(r["failed_steps"]) == 0 and float(r["newton_per_stage"]) >= 1
    tr = next(r for r in rows if r["method"] == "tr_bdf2")  # two stages per step
    assert float(tr["newton_per_step"]) == pytest.approx(2 * float(tr["newton_per_stage"]), rel=0.3)
    assert "### Within 1 cm" in (tmp_path / "stiff_regime.md").read_text()
    pytest.importorskip("matplotlib")
    assert (tmp_path / "stiff_regime.png").stat().st_size > 1000
    (tmp_path / "stiff_regime.png").unlink()
    assert sr.main(["--replot", "--out", str(tmp_path)]) == 0  # from the CSV alone
    assert (tmp_path / "stiff_regime.png").stat().st_size > 1000


def test_stiff_regime_crossings():
    """The crossing of an implicit line with the explicit trend C n^3 sqrt(ke): interpolated inside the measured
    range, extrapolated (the cost held) outside it; the trend's C from symplectic Euler's rows."""
    from benchmarks import stiff_regime as sr

    def row(method, ke, cpu, n=2):
        return dict(n=n, ke=ke, method=method, target=0.01, cpu_per_frame_s=cpu, reached=True, decidable=True)

    se = [row("symplectic_euler", k, 3.0 * 8 * math.sqrt(k)) for k in (1e6, 1e8)]
    C = sr.explicit_fit(se)
    assert C == pytest.approx(3.0)
    # trend at n = 2: 24 sqrt(ke): 2.4e4 at 1e6, 2.4e5 at 1e8; a flat implicit line at 7.59e4 crosses at 1e7
    flat = [row("tr_bdf2", k, 24 * math.sqrt(1e7)) for k in (1e6, 1e8)]
    (c,) = sr.crossings(se + flat, C)
    assert not c["extrapolated"] and c["ke"] == pytest.approx(1e7, rel=1e-9)
    cheap = [row("bdf2", 1e8, 1.0)]  # below the trend everywhere measured: extrapolated below
    (c,) = sr.crossings(se + cheap, C)
    assert c["extrapolated"] and c["ke"] == pytest.approx((1.0 / 24) ** 2)


def test_stiff_convergence_quick(tmp_path):
    """``python -m benchmarks stiff-convergence --quick``: one row per (ke, integrator), every step converged."""
    from benchmarks import stiff_convergence as mod

    assert mod.main(["--quick", "--out", str(tmp_path)]) == 0
    rows, cols = _read(tmp_path / "stiff_convergence.csv")
    assert list(cols) == mod.COLUMNS and len(rows) == 6
    assert all(r["failed_steps"] == "0" and float(r["newton_per_stage"]) >= 1 for r in rows)
