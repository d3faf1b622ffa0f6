"""springsim's benchmark suite: speed *and* error, one entry point.

Run ``python -m benchmarks`` for the list of benchmarks and ``python -m benchmarks NAME --help``
for one's options, e.g.::

    python -m benchmarks cloth-grid --n 128 --steps 30 --warmup 9 --solver amg-cg --rtol 1e-6

Cases come from :mod:`springsim.scene.gallery` (the benchmark cloth and the accuracy cloth) and the
shipped scenes; energies and spectral estimates from the library (:mod:`springsim.run.energy`,
:mod:`springsim.analysis`); tables, CSV files and plots are written by :mod:`benchmarks.common` into
``benchmarks/results/`` (git-ignored). Every benchmark reports speed together with an error, measured
against a reference of the ODE (:mod:`springsim.analysis.reference`) or, for linear solves, the direct
solution. Their smoke tests (``tests/unit/test_benchmarks.py`` and friends) run them at tiny sizes
under the ``slow`` marker, which CI runs.
"""

#: Benchmark name -> module (``python -m benchmarks NAME``).
BENCHMARKS = {
    "speed-vs-error": "speed_vs_error",
    "accuracy": "accuracy",
    "frame-cost": "frame_cost",
    "cloth-grid": "cloth_grid",
    "scaling": "scaling",
    "linear-solve-error": "linear_solve_error",
    "sparse-vs-dense": "sparse_vs_dense",
    "jacobian-modes": "jacobian_modes",
    "blas-threads": "blas_threads",
    "explicit-speed": "explicit_speed",
    "distributed": "distributed",
    "stiffness-sweep": "stiffness_sweep",
    "explicit-limit": "explicit_limit",
    "stiff-regime": "stiff_regime",
    "stiff-convergence": "stiff_convergence",
    "peer-newton": "peer_newton",
    "scene-read": "scene_read",
}
