"""benchmarks/frame_cost.py at a tiny size: it runs and writes its columns, errors are against a converged
reference of the ODE (not the method itself), and the explicit limit is verified."""

from __future__ import annotations

import argparse
import csv
import importlib
import math
from pathlib import Path

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
    assert fc.main(["--quick", "--out", str(tmp_path), "--cache-dir", str(tmp_path / "ref")]) == 0
    rows, cols = _read(tmp_path / "frame_cost.csv")
    assert cols == fc.COLUMNS and len(rows) == 1
    r = rows[0]
    assert int(r["n"]) == 6 and int(r["dofs"]) == 3 * 6 * 5 and int(r["frames"]) == fc.DEFAULT_FRAMES
    assert r["status"] == "ok" and r["ref_usable"] == "True"
    assert r["force_kernels"] == "numpy"  # "auto" on a cloth below ForceSpring.auto_min_pairs springs
    assert float(r["floor"]) < float(r["err_rms"]) < 0.01 and float(r["cpu_per_frame_s"]) > 0
    assert float(r["floor"]) == max(float(r["ref_pair_diff"]), float(r["xcheck_diff"]))
    assert float(r["se_err_rms"]) < 0.01 and float(r["se_cpu_per_frame_s"]) > 0 and r["se_window_finite"] == "True"
    # the explicit count is the one computed from omega, verified stable; 0.7x of it is not
    S = int(r["se_substeps"])
    assert S == int(r["substeps_computed"]) == fc.explicit_substeps(float(r["omega_max"]))
    assert r["se_stable"] == "True" and r["se_lower_unstable"] == "True"
    assert int(r["se_lower_substeps"]) == math.floor(0.7 * S) < S
    assert float(r["omega_max"]) <= float(r["omega_gershgorin"]) * (1 + 1e-12)
    # the reference: Verlet at 2S, 4S, 8S substeps per frame, each refinement ~4x closer (second order)
    assert int(r["ref_substeps"]) == 8 * S and r["ref_method"] == "verlet"
    cand, ccols = _read(tmp_path / "frame_cost_candidates.csv")
    assert ccols == fc.CANDIDATE_COLUMNS
    assert {c["role"] for c in cand} == {"reference", "cross-check", "explicit", "candidate"}
    diffs = [float(c["diff_to_next"]) for c in cand if c["role"] == "reference" and c["diff_to_next"]]
    assert len(diffs) == 2 and diffs[1] < diffs[0] / 3
    assert [float(x) for x in r["ref_median_ratios"].split()] == pytest.approx([4.0], rel=0.1)
    measured = [c for c in cand if c["role"] == "candidate" and c["err_rms"]]
    assert any(c["status"] == "within target" for c in measured)
    assert any(c["status"] != "within target" for c in measured)
    for c in measured:  # the error is the max over the frames run; a stopped run's is a lower bound
        assert float(c["err_rms"]) >= float(c["floor"])
        assert (c["err_lower_bound"] == "True") == c["status"].startswith("stopped")
    assert "| n | ke | dofs | frames | floor | config |" in (tmp_path / "frame_cost.md").read_text()
    # a rerun loads every reference from the cache and measures the same errors
    assert fc.main(["--quick", "--out", str(tmp_path / "again"), "--cache-dir", str(tmp_path / "ref")]) == 0
    again, _ = _read(tmp_path / "again" / "frame_cost_candidates.csv")
    assert [c["status"] for c in again if c["role"] in ("reference", "cross-check")] == ["cached"] * 4
    assert ({c["config"]: c["err_raw"] for c in again if c["role"] != "reference"}
            == {c["config"]: c["err_raw"] for c in cand if c["role"] != "reference"})


def test_candidate_over_the_budget_stops_with_lower_bounds(fc, tmp_path, monkeypatch):
    """A candidate still running when the size's budget runs out stops after that frame: its error and its cost
    per frame (the CPU spent, over the whole window) are lower bounds, and the tables say so."""
    track = fc.track_errors

    def spent(*args, **kw):  # the candidates' deadline has passed; symplectic Euler has none and runs through
        return track(*args, **{**kw, "deadline": 0.0} if kw.get("deadline") is not None else kw)

    monkeypatch.setattr(fc, "track_errors", spent)
    assert fc.main(["--quick", "--out", str(tmp_path), "--cache-dir", str(tmp_path / "ref")]) == 0
    cand, _ = _read(tmp_path / "frame_cost_candidates.csv")
    late = [c for c in cand if c["role"] == "candidate" and c["err_rms"]]
    assert late and all(c["status"].startswith("stopped at frame 1: over the budget") for c in late)
    for c in late:
        assert c["cost_lower_bound"] == "True" and c["err_lower_bound"] == "True" and int(c["frames_run"]) == 1
        assert float(c["cpu_per_frame_s"]) == pytest.approx(float(c["cpu_s"]) / fc.DEFAULT_FRAMES)
    se = [c for c in cand if c["role"] == "explicit"][0]
    assert int(se["frames_run"]) == fc.DEFAULT_FRAMES and se["cost_lower_bound"] == "False"
    assert "> " in (tmp_path / "frame_cost.md").read_text().split("### Every run")[1]


def test_candidate_equal_to_the_reference_has_no_error(fc, tmp_path):
    """Errors are against the reference at every frame: the reference's own configuration measures 0 (reported as
    below the floor), another explicit method at the same step does not."""
    out = tmp_path / "out"
    assert fc.main(["--quick", "--out", str(out), "--no-cache", "--cross-check-max-n", "0", "--ref-substeps", "10",
                    "--ref-levels", "2", "--measure-all", "--candidates", "verlet:1200:none",
                    "symplectic_euler:1200:none"]) == 0
    rows, _ = _read(out / "frame_cost_candidates.csv")
    floor = float(next(r for r in rows if r["role"] == "reference")["diff_to_next"])
    same = next(r for r in rows if r["config"] == "verlet h=1/1200")
    assert float(same["err_raw"]) == 0.0 and same["below_floor"] == "True" and float(same["err_rms"]) == floor
    se = next(r for r in rows if r["config"] == "symplectic_euler h=1/1200")
    assert 0.0 < float(se["err_raw"]) < 0.01
    summary, _ = _read(out / "frame_cost.csv")
    assert summary[0]["status"] == "ok" and summary[0]["config"] in (same["config"], se["config"])


def test_error_is_against_the_reference_not_the_method_itself(fc):
    """Linearized implicit Euler at 1/60 s on the 6 x 6 cloth: its error against the validated reference is larger
    than against itself at an 8x smaller step, and far larger than that self-referenced error at 0.25 s."""
    from benchmarks import reference_cache as rc

    model = fc.cloth(6)
    ref = rc.refined_reference(model, 10, 3, fc.DEFAULT_FRAMES, case="test", cache_dir=None)
    assert ref.finite and ref.shrinking and ref.floor < 1e-3

    def frames_of(hinv):
        c = fc.parse_candidate(f"linearized_implicit:{hinv}:direct")
        run = fc.make_run(model, c, {})
        q = [run.positions.copy()]
        for _ in range(fc.DEFAULT_FRAMES):
            assert run.advance(c.steps_per_frame)
            q.append(run.positions.copy())
        return np.array(q)

    coarse, fine = frames_of(60), frames_of(480)
    true = rc.frame_rms(coarse, ref.q)
    self_ref = rc.frame_rms(coarse, fine)
    assert true.max() > 1.1 * self_ref.max() > 0.1  # first order: the self-referenced error is ~7/8 of the true one
    assert true.max() > 5 * self_ref[15]  # the former protocol: at 0.25 s (15 frames) only, against itself
    res = fc.track_errors(fc.make_run(model, fc.parse_candidate("linearized_implicit:60:direct"), {}), 1, ref.q)
    assert res["err_max"] == true.max() and res["err_frame"] == int(np.argmax(true)) and not res["stopped"]
    stopped = fc.track_errors(fc.make_run(model, fc.parse_candidate("linearized_implicit:60:direct"), {}), 1, ref.q,
                              stop_above=0.05)
    assert stopped["stopped"] and stopped["err_max"] > 0.05 and stopped["frames_run"] < fc.DEFAULT_FRAMES
    assert np.all(true[:stopped["frames_run"]] <= 0.05)
    import time

    late = fc.track_errors(fc.make_run(model, fc.parse_candidate("linearized_implicit:60:direct"), {}), 1, ref.q,
                           deadline=time.perf_counter())  # the budget is spent: it stops after its first frame
    assert late["out_of_time"] and late["frames_run"] == 1 and late["err_max"] == true[1] and not late["stopped"]


def test_reference_converges_and_agrees_with_solve_ivp(fc, tmp_path):
    """Verlet levels converge at second order before the buckling; the finest agrees with Radau within the floor;
    the cache is keyed by the model's fingerprint."""
    from benchmarks import reference_cache as rc

    model = fc.cloth(6)
    frames = 20
    ref = rc.refined_reference(model, 10, 4, frames, case="c6", cache_dir=tmp_path)
    assert ref.shrinking and all(3.5 < x < 4.5 for x in ref.ratios) and not any(ref.cached)
    radau = rc.cached_frames(model, "Radau", 0, frames, case="c6", cache_dir=tmp_path)
    assert float(np.max(rc.frame_rms(radau["q"], ref.q))) < ref.floor
    again = rc.refined_reference(model, 10, 4, frames, case="c6", cache_dir=tmp_path)
    assert all(again.cached) and np.array_equal(again.q, ref.q) and again.diffs == ref.diffs
    from springsim.scene import benchmark_cloth

    softer = benchmark_cloth(6, stiffness=1e3, stiffness_shear=1e3, stiffness_bend=50.0)  # another fingerprint
    other = rc.refined_reference(softer, 10, 2, frames, case="c6", cache_dir=tmp_path)
    assert other.finite and not any(other.cached)


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
                                  "tr_bdf2:60:nosuch", "tr_bdf2:90:auto", "nosuch:60:none", "verlet:60:direct",
                                  "tr_bdf2:60:auto:forcing", "tr_bdf2:60:auto:1x=2", "verlet:60:none:a=1",
                                  "tr_bdf2:60:auto:a=1:b=2"])
def test_candidate_errors_name_the_field(fc, text):
    with pytest.raises(argparse.ArgumentTypeError, match="^--candidates: "):
        fc.parse_candidate(text)


def test_parse_candidate(fc):
    c = fc.parse_candidate("tr_bdf2:240:amg-cg")
    assert (c.method, c.h, c.solver) == ("tr_bdf2", 1 / 240, "amg-cg") and c.label == "tr_bdf2 h=1/240 amg-cg"
    assert c.implicit and c.steps_per_frame == 4
    c = fc.parse_candidate("tr_bdf2:120:auto:forcing=eisenstat-walker,forcing_max=0.3,newton_maxiter=20")
    assert c.options == (("forcing", "eisenstat-walker"), ("forcing_max", 0.3), ("newton_maxiter", 20))
    assert fc.parse_candidate("tr_bdf2:120:auto:line_search=False").options == (("line_search", False),)
    assert c.label == "tr_bdf2 h=1/120 auto forcing=eisenstat-walker forcing_max=0.3 newton_maxiter=20"
    model = fc.cloth(4)
    run = fc.make_run(model, c, {"newton_maxiter": 50})
    assert run.integ.options.forcing == "eisenstat-walker" and run.integ.newton_maxiter == 20  # the candidate's own win
    e = fc.parse_candidate("verlet:1200:none")
    assert not e.implicit and e.steps_per_frame == 20 and e.label == "verlet h=1/1200"


def test_force_kernels_reach_the_runs(fc):
    """``--force-kernels`` reaches symplectic Euler and the implicit candidates; the summary names what it used."""
    from springsim._runtime.accel import numba_available

    model = fc.cloth(6)
    assert fc.force_kernels_used(model, "auto") == fc.force_kernels_used(model, "numpy") == "numpy"
    if not numba_available():
        return
    assert fc.force_kernels_used(model, "numba") == "numba"
    for text in ("symplectic_euler:600:none", "verlet:600:none", "tr_bdf2:60:direct"):
        run = fc.make_run(model, fc.parse_candidate(text), {"force_kernels": "numba"})
        terms = run.terms if hasattr(run, "terms") else run.integ.terms
        assert [t.kernels for t in terms if t.name == "spring"] == ["numba"], text


@pytest.mark.slow
def test_stiffness_sweep_quick(tmp_path):
    """``python -m benchmarks stiffness-sweep --quick``: one row per (ke, method) with the cheapest configuration
    within the target, symplectic Euler's substeps growing with the stiffness, and the plot."""
    from benchmarks import stiffness_sweep as sw

    assert sw.main(["--quick", "--out", str(tmp_path)]) == 0
    rows, cols = _read(tmp_path / "stiffness_sweep.csv")
    assert cols == sw.COLUMNS
    assert {(float(r["ke"]), r["method"]) for r in rows} == {(k, m) for k in (1e3, 1e4) for m in
                                                           ("symplectic_euler", "linearized_implicit", "tr_bdf2")}
    se = sorted((r for r in rows if r["method"] == "symplectic_euler"), key=lambda r: float(r["ke"]))
    assert all(r["reached"] == "True" for r in se) and int(se[0]["se_substeps"]) < int(se[1]["se_substeps"])
    for r in rows:
        assert (r["reached"] == "True") == (float(r["err_rms"]) < 0.01) and float(r["cpu_per_frame_s"]) > 0
        assert r["decidable"] == str(float(r["floor"]) < 0.01)
    pytest.importorskip("matplotlib")
    assert (tmp_path / "stiffness_sweep.png").stat().st_size > 1000
    (tmp_path / "stiffness_sweep.png").unlink()
    assert sw.main(["--replot", "--out", str(tmp_path)]) == 0  # the plot again, from the CSV alone
    assert (tmp_path / "stiffness_sweep.png").stat().st_size > 1000
    # with the shipped sweep's rows merged in (docs/stiffness_sweep.csv, the data of the plot in BENCHMARKS.md#stiffness-sweep)
    shipped = Path(__file__).resolve().parents[2] / "docs" / "stiffness_sweep.csv"
    assert sw.main(["--replot", "--out", str(tmp_path), "--merge", str(shipped)]) == 0


def test_stiffness_sweep_merge_replaces_same_size_stiffness_and_method():
    """The shipped sweep data loads with its types, and a new row replaces the one of its (n, ke, method,
    force kernels)."""
    from benchmarks import stiffness_sweep as sw

    shipped = sw.load(Path(__file__).resolve().parents[2] / "docs" / "stiffness_sweep.csv", 0.01)
    assert {r["n"] for r in shipped} >= {32, 64} and all(isinstance(r["reached"], bool) for r in shipped)
    for r in shipped:
        assert r["reached"] == (r["err_rms"] < 0.01) and r["decidable"] == (r["floor"] < 0.01)
    new = {**shipped[0], "cpu_per_frame_s": 123.0}
    extra = {**shipped[0], "n": 999}
    merged = sw.merge(shipped, [new, extra])
    assert len(merged) == len(shipped) + 1
    assert [r["cpu_per_frame_s"] for r in merged if (r["n"], r["ke"], r["method"]) ==
            (new["n"], new["ke"], new["method"])] == [123.0]
    # rows measured with the compiled force pass are their own line; the shipped rows without the column are numpy's
    assert {r["force_kernels"] for r in shipped} <= {"numpy", "numba"}
    compiled = {**shipped[0], "force_kernels": "numba", "cpu_per_frame_s": 1.0}
    assert len(sw.merge(shipped, [compiled])) == len(shipped) + 1
    assert sw.label(compiled) == compiled["method"] + " (compiled forces)"
    assert sw.label(shipped[0]) == compiled["method"]


def test_stiffness_sweep_prefers_whole_runs_when_none_is_within():
    """A run stopped by the budget (its error covers only its first frames) is a method's row only when the method
    has no other; the row keeps the lower-bound flags."""
    from benchmarks import stiffness_sweep as sw

    summary = {"n": "64", "ke": "1e6", "floor": "0.001", "se_substeps": "100", "force_kernels": "numpy"}
    se = {"role": "explicit", "method": "symplectic_euler", "status": "within target", "err_rms": "0.002",
          "cpu_per_frame_s": "1.0", "config": "se", "err_lower_bound": "False", "cost_lower_bound": "False"}
    late = {"role": "candidate", "method": "tr_bdf2", "status": "stopped at frame 3: over the budget",
            "err_rms": "0.001", "cpu_per_frame_s": "5.0", "config": "late", "err_lower_bound": "True",
            "cost_lower_bound": "True"}
    whole = {**late, "status": "above target", "err_rms": "0.03", "cpu_per_frame_s": "2.0", "config": "whole",
             "err_lower_bound": "False", "cost_lower_bound": "False"}
    rows = {r["method"]: r for r in sw.best_per_method(summary, [se, late, whole], 0.01)}
    assert rows["symplectic_euler"]["reached"] and rows["tr_bdf2"]["config"] == "whole"
    assert not rows["tr_bdf2"]["reached"] and not rows["tr_bdf2"]["cost_lower_bound"]
    only = {r["method"]: r for r in sw.best_per_method(summary, [se, late], 0.01)}["tr_bdf2"]
    assert only["config"] == "late" and only["cost_lower_bound"] and only["err_lower_bound"] and not only["reached"]


def test_stiffness_sweep_passes_cross_check_limit(tmp_path, monkeypatch):
    """``--cross-check-max-n`` reaches every frame-cost run of the sweep (0: no solve_ivp cross-check, for
    stiffnesses where it cannot finish), and is left to frame-cost's default when not given."""
    from benchmarks import frame_cost as fc
    from benchmarks import stiffness_sweep as sw

    calls = []

    def fake_main(args):
        calls.append(list(args))
        out = Path(args[args.index("--out") + 1])
        out.mkdir(parents=True, exist_ok=True)
        (out / "frame_cost.csv").write_text("n\n")
        (out / "frame_cost_candidates.csv").write_text("n\n")
        return 0

    monkeypatch.setattr(fc, "main", fake_main)
    monkeypatch.setattr(sw, "plot", lambda *a, **k: False)
    assert sw.main(["--sizes", "64", "--ke", "1e6", "1e7", "--cross-check-max-n", "0", "--out", str(tmp_path)]) == 0
    assert len(calls) == 2 and all(c[c.index("--cross-check-max-n") + 1] == "0" for c in calls)
    calls.clear()
    assert sw.main(["--sizes", "64", "--ke", "1e6", "--out", str(tmp_path)]) == 0
    assert len(calls) == 1 and "--cross-check-max-n" not in calls[0]
    assert calls[0][calls[0].index("--force-kernels") + 1] == "auto"
    calls.clear()
    assert sw.main(["--sizes", "64", "--ke", "1e6", "--force-kernels", "numpy", "--out", str(tmp_path)]) == 0
    assert calls[0][calls[0].index("--force-kernels") + 1] == "numpy"


def test_damping_reaches_every_spring_and_the_cache_key(fc, tmp_path):
    """``--damping``: every spring of the cloth gets it, the reference is cached apart from the undamped one's, and
    the damped reference still converges; the summary records it."""
    undamped, damped = fc.cloth(4, 1e4), fc.cloth(4, 1e4, 0.02)
    assert np.all(undamped.spring_damping == 0.0) and np.all(damped.spring_damping == 0.02)
    assert np.array_equal(damped.spring_stiffness, undamped.spring_stiffness)
    assert np.all(fc.cloth(4, None, 0.02).spring_damping == 0.02)  # the accuracy cloth's stiffnesses, damped
    args = ["--quick", "--sizes", "4", "--ke", "1e4", "--frames", "4", "--cross-check-max-n", "0", "--candidates",
            "--cache-dir", str(tmp_path / "ref")]
    assert fc.main(args + ["--damping", "0.02", "--out", str(tmp_path / "d")]) == 0
    assert fc.main(args + ["--out", str(tmp_path / "u")]) == 0
    names = sorted(p.name for p in (tmp_path / "ref").iterdir())
    assert len(names) == 6 and sum("_kd0.02_" in x for x in names) == 3
    (d,), _ = _read(tmp_path / "d" / "frame_cost.csv")
    (u,), _ = _read(tmp_path / "u" / "frame_cost.csv")
    assert float(d["damping"]) == 0.02 and float(u["damping"]) == 0.0
    assert 0 < float(d["floor"]) < 1e-4 and float(d["floor"]) != float(u["floor"])
    with pytest.raises(SystemExit):
        fc.main(["--quick", "--damping", "-1"])
