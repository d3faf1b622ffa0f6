"""``benchmarks/accuracy.py`` at a tiny size: it runs, writes its tables,
caches the reference and measures the growth of a perturbation."""

from __future__ import annotations

import csv
import importlib

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # the benchmarks at tiny sizes



@pytest.fixture()
def acc(tmp_path, monkeypatch):
    mod = importlib.import_module("benchmarks.accuracy")
    monkeypatch.setattr(mod, "RESULTS", tmp_path)
    monkeypatch.setitem(mod.SOLVER, "name", "direct")
    monkeypatch.setitem(mod.SOLVER, "ref_name", "direct")
    return mod


def _rows(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_run_size_writes_tables_and_caches_the_reference(acc, tmp_path, capsys):
    acc.run_size(3, 40, [10, 20], [1e-2], fixed_methods=("implicit_euler", "tr_bdf2"), adaptive_methods=("tr_bdf2",))
    assert (tmp_path / "accuracy_reference_n3_steps40.npz").exists()
    assert "reference saved" in capsys.readouterr().out
    h60 = _rows(tmp_path / "accuracy_at_animation_steps_h60_n3.csv")
    assert [r["method"] for r in h60] == ["implicit_euler", "bdf2", "tr_bdf2", "energy_momentum", "trapezoidal"]
    err = {r["method"]: float(r["rms_err_m"]) for r in h60}
    assert all(np.isfinite(e) and e >= 0 for e in err.values())
    assert err["tr_bdf2"] < err["implicit_euler"]  # second order beats first order at the same step
    sweep = _rows(tmp_path / "accuracy_at_animation_steps_sweep_n3.csv")
    assert {r["method"] for r in sweep} == {"implicit_euler", "tr_bdf2", "tr_bdf2+adaptive"}
    assert set(sweep[0]) == {"n", "method", "h_or_tol", "mean_h_s", "rms_err_m", "cpu_per_sim_s", "newton_failures"}
    ie = [float(r["rms_err_m"]) for r in sweep if r["method"] == "implicit_euler"]
    assert ie[1] < ie[0]  # halving the step reduces the error
    cost = _rows(tmp_path / "accuracy_at_animation_steps_cost_n3.csv")
    assert [r["method"] for r in cost] == ["implicit_euler", "tr_bdf2", "tr_bdf2+adaptive"]
    # a second run loads the saved reference instead of recomputing it
    acc.run_size(3, 40, [10], [1e-2], sweep=False)
    assert "reference loaded" in capsys.readouterr().out


def test_sensitivity_starts_at_the_perturbation(acc, tmp_path):
    acc.sensitivity(3, 20, delta=1e-9, frames=4)
    rows = _rows(tmp_path / "accuracy_at_animation_steps_sensitivity_n3_delta1e-09.csv")
    assert float(rows[0]["t_s"]) == 0.0
    assert float(rows[0]["rms_diff_m"]) == pytest.approx(1e-9)
    assert float(rows[-1]["t_s"]) == pytest.approx(acc.T_END)
    assert all(np.isfinite(float(r["rms_diff_m"])) for r in rows)


def test_command_line_selects_solvers(acc, tmp_path):
    acc.main(["--sensitivity", "3", "10", "--solver", "direct", "--ref-solver", "dense"])
    assert acc.SOLVER["name"] == "direct" and acc.SOLVER["ref_name"] == "dense"
    assert (tmp_path / "accuracy_at_animation_steps_sensitivity_n3_delta1e-09.csv").exists()


def test_t_end_tags_the_output(acc, tmp_path, monkeypatch):
    monkeypatch.setattr(acc, "T_END", acc.T_END)  # restored after the test
    acc.main(["--t-end", "0.2", "--sensitivity", "3", "10"])
    rows = _rows(tmp_path / "accuracy_at_animation_steps_sensitivity_n3_delta1e-09_T0.2.csv")
    assert float(rows[-1]["t_s"]) == pytest.approx(0.2)
    with pytest.raises(SystemExit):
        acc.main(["--t-end", "-1", "--sensitivity", "3", "10"])


def test_refined_reference_reuses_the_saved_one_as_twin(acc, tmp_path, capsys):
    model = acc.cloth(3)
    q20, _, _, _ = acc.reference(model, 3, 20)
    q40, _, twin, info = acc.reference(model, 3, 40)
    assert "twin loaded from accuracy_reference_n3_steps20.npz" in capsys.readouterr().out
    np.testing.assert_array_equal(twin, q20)
    assert info["ref_steps"] == 40 and acc.rms(q40, twin) < acc.rms(q20, model.particle_q)


def test_newton_limit_option(acc, tmp_path, monkeypatch):
    monkeypatch.setattr(acc, "NEWTON_MAXITER", acc.NEWTON_MAXITER)
    monkeypatch.setattr(acc, "T_END", acc.T_END)
    acc.main(["--sizes", "3", "--ref-steps", "20", "--validate-n", "0", "--no-sweep", "--skip-spring",
              "--h60-methods", "bdf2", "--newton-maxiter", "7", "--t-end", "0.2"])
    assert acc.NEWTON_MAXITER == 7
    rows = _rows(tmp_path / "accuracy_at_animation_steps_h60_n3_newton7_T0.2.csv")
    assert [r["method"] for r in rows] == ["bdf2"]


def test_sweep_never_measures_the_reference_against_itself(acc, tmp_path):
    acc.run_size(3, 40, [10, 20, 40], [1e-2], h60=False, fixed_methods=("tr_bdf2",), adaptive_methods=())
    sweep = _rows(tmp_path / "accuracy_at_animation_steps_sweep_n3.csv")
    assert [float(r["mean_h_s"]) for r in sweep] == [pytest.approx(acc.T_END / 10)]


def test_newton_jacobian_modes_runs_each_configuration(acc, tmp_path, capsys):
    """``python -m benchmarks jacobian-modes`` at a tiny size: one row per method and configuration,
    the default Jacobian resolved, escalation switchable, bad configurations rejected."""
    mod = importlib.import_module("benchmarks.jacobian_modes")
    mod.acc = acc  # the fixture's module (results in tmp_path)
    mod.main(["--n", "3", "--steps", "8", "--ref-steps", "40", "--ref-solver", "direct", "--methods", "tr_bdf2",
              "--configs", "direct:default", "direct:spd:noescalate", "cg:default"])
    rows = _rows(tmp_path / "accuracy_at_animation_steps_newton_jacobian_modes_n3.csv")
    assert [(r["solver"], r["jacobian"], r["escalate"]) for r in rows] == [
        ("direct", "exact", "True"), ("direct", "spd", "False"), ("cg", "spd", "True")]
    assert all(float(r["rms_error_m"]) < 0.05 and r["steps_at_limit"] == "0" for r in rows)
    with pytest.raises(SystemExit):
        mod.main(["--n", "3", "--steps", "8", "--ref-steps", "40", "--configs", "direct"])
    assert "expected solver:jacobian" in capsys.readouterr().err


def test_h_max_caps_the_adaptive_steps_and_tags_the_output(acc, tmp_path, monkeypatch):
    monkeypatch.setattr(acc, "H_MAX", None)  # restored after the test
    acc.main(["--sizes", "3", "--ref-steps", "40", "--validate-n", "0", "--skip-spring", "--only-adaptive", "tr_bdf2",
              "--tols", "1e-2", "--h-max", "0.05"])
    rows = _rows(tmp_path / "accuracy_at_animation_steps_adaptive_tr_bdf2_n3_hmax0.05.csv")
    assert len(rows) == 1 and float(rows[0]["mean_h_s"]) <= 0.05 + 1e-12
    capped = acc.adaptive_run(acc.cloth(3), "tr_bdf2", 1e-2)[3]
    assert capped.adaptive_stats["h_max"] <= 0.05 + 1e-12
    monkeypatch.setattr(acc, "H_MAX", None)
    free = acc.adaptive_run(acc.cloth(3), "tr_bdf2", 1e-2)[3]
    assert free.adaptive_stats["h_max"] > 0.05  # without the cap the controller takes longer steps here
    with pytest.raises(SystemExit):
        acc.main(["--h-max", "0", "--sensitivity", "3", "10"])
