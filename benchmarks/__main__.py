"""``python -m benchmarks NAME [options]``: run one benchmark; without a name, list them."""

from __future__ import annotations

import importlib
import sys

from . import BENCHMARKS


def main(argv: list[str] | None = None) -> int:
    if argv is None:  # run as a program: the command line's allocator policy (springsim._runtime.alloc)
        from springsim._runtime.alloc import retain_freed_memory

        retain_freed_memory()
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help", "list"):
        print("usage: python -m benchmarks NAME [options]   (python -m benchmarks NAME --help)\n\nbenchmarks:")
        for name, module in BENCHMARKS.items():
            doc = (importlib.import_module(f"benchmarks.{module}").__doc__ or "").strip().splitlines()
            print(f"  {name:<20} {doc[0] if doc else ''}")
        return 0
    name = argv[0]
    if name not in BENCHMARKS:
        print(f"python -m benchmarks: error: unknown benchmark {name!r}; choose one of {', '.join(BENCHMARKS)}",
              file=sys.stderr)
        return 2
    module = importlib.import_module(f"benchmarks.{BENCHMARKS[name]}")
    sys.argv[0] = f"python -m benchmarks {name}"  # argparse names the command so
    return int(module.main(argv[1:]) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
