"""A scene file under mpiexec: read whole and scattered, or read in pieces; time and peak memory per rank.

``python -m benchmarks scene-read --n 500 --ranks 1 2`` writes an explicit YAML cloth of ``n x n`` particles (its
first row fixed, structural springs: about ``4.6 n^2`` lines) to a temporary directory and, for each rank count,
builds every rank's part (:class:`springsim.distributed.ScenePart`) two ways, each in its own processes:

* ``whole``: rank 0 loads the scene (:func:`springsim.scene.load_scene`), then sends every rank its part of the
  model (:func:`springsim.distributed.scatter_model`): what the command line did before the file was read in pieces.
* ``pieces``: rank 0 reads the small sections, then the item lists a chunk at a time, sending them on
  (:func:`springsim.distributed.streamed_part`): what ``springsim run`` does now.

Reported: wall time of the construction, the largest and the smallest rank's peak resident set (``ru_maxrss``) and,
as the error column, whether the whole model's fingerprint that every rank holds equals the fingerprint of the model
built serially (the parts themselves are checked equal to the bit in the tests). Needs petsc4py and mpi4py (the
petsc environment of docs/distributed.md). Run alone: the figures are of this machine and its load (printed).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .common import fmt, machine_info, markdown_table, write_csv
from .distributed import _mpiexec

COLUMNS = ["mode", "ranks", "particles", "springs", "file_mb", "build_s", "max_rss_mb", "min_rss_mb",
           "fingerprint_ok", "load"]


def write_cloth(path: Path, n: int) -> int:
    """An ``n x n`` cloth in the assignment's format (first row fixed, structural springs); its spring count."""
    springs = 0
    with open(path, "w") as f:
        f.write("solver: {type: linearized_implicit, timestep: 0.0166667, steps: 1, jacobian: spd}\nparticles:\n")
        for k in range(n * n):
            i, j = k % n, k // n
            f.write(f"  - {{pos: [{0.01 * i:.4f}, {0.01 * j:.4f}, 1.0], mass: 0.001"
                    f"{', fixed: true' if j == 0 else ''}}}\n")
        f.write("springs:\n")
        for k in range(n * n):
            if k % n < n - 1:
                f.write(f"  - {{particle_ids: [{k}, {k + 1}], stiffness: 1000.0, damping: 0.1}}\n")
                springs += 1
            if k // n < n - 1:
                f.write(f"  - {{particle_ids: [{k}, {k + n}], stiffness: 1000.0, damping: 0.1}}\n")
                springs += 1
    return springs


def worker(argv) -> int:
    """``--worker MODE SCENE OUT``: under mpiexec, build every rank's part; rank 0 writes the figures."""
    mode, scene, out = argv
    from springsim.distributed import import_petsc, scatter_model, streamed_part
    from springsim.scene import load_scene

    _, MPI = import_petsc()
    comm = MPI.COMM_WORLD
    comm.Barrier()
    t = time.perf_counter()
    if mode == "pieces":
        s = comm.bcast(load_scene(scene, build=False) if comm.rank == 0 else None, root=0)
        part = streamed_part(s, comm)
    else:
        model = load_scene(scene).model if comm.rank == 0 else None
        part = scatter_model(model, comm)
        del model
    comm.Barrier()
    wall = time.perf_counter() - t
    rss = comm.gather(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, root=0)
    fps = comm.gather(part.fingerprint(), root=0)
    if comm.rank == 0:
        Path(out).write_text(json.dumps(dict(build_s=wall, rss=rss, fingerprints=fps)))
    return 0


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] == "--worker":
        return worker(argv[1:])
    p = argparse.ArgumentParser(prog="python -m benchmarks scene-read", description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=500, help="cloth side (default 500: 250,000 particles)")
    p.add_argument("--ranks", type=int, nargs="+", default=[1, 2])
    p.add_argument("--modes", nargs="+", choices=("whole", "pieces"), default=["whole", "pieces"])
    p.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    a = p.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        scene = Path(tmp) / "cloth.yaml"
        springs = write_cloth(scene, a.n)
        from springsim.scene import load_scene

        reference = load_scene(scene).model.fingerprint()  # serially, before the timed runs
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
        for ranks in a.ranks:
            for mode in a.modes:
                out = Path(tmp) / f"{mode}_{ranks}.json"
                load = os.getloadavg()[0]
                subprocess.run(_mpiexec(ranks) + [sys.executable, "-m", "benchmarks.scene_read", "--worker", mode,
                                                  str(scene), str(out)],
                               check=True, env=env, cwd=Path(__file__).resolve().parents[1])
                r = json.loads(out.read_text())
                row = dict(mode=mode, ranks=ranks, particles=a.n * a.n, springs=springs,
                           file_mb=scene.stat().st_size / 1e6, build_s=r["build_s"], max_rss_mb=max(r["rss"]),
                           min_rss_mb=min(r["rss"]), fingerprint_ok=all(f == reference for f in r["fingerprints"]),
                           load=load)
                rows.append(row)
                print("  " + ", ".join(f"{k} {fmt(row[k])}" for k in COLUMNS), flush=True)
    write_csv(a.out / "scene_read.csv", rows, COLUMNS)
    (a.out / "scene_read.json").write_text(json.dumps(dict(machine=machine_info(), rows=rows), indent=1))
    md = markdown_table(rows, COLUMNS)
    (a.out / "scene_read.md").write_text(md + "\n")
    print(md)
    return 0 if all(r["fingerprint_ok"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
