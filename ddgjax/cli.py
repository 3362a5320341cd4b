"""The `ddgjax` console script's entry point, `main`; the command line itself lives in `ddgjax._cli`."""

from __future__ import annotations

import sys

from ._cli import main

if __name__ == "__main__":
    sys.exit(main())
