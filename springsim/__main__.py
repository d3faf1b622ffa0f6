"""``python -m springsim``: the command-line interface (see :mod:`springsim.cli`)."""

import sys

from .cli import main

__all__: list[str] = []

sys.exit(main())
