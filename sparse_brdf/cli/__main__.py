"""``python -m sparse_brdf.cli``: the ``sparse-brdf`` command."""

from __future__ import annotations

import sys

from ._entry import main

if __name__ == "__main__":
    sys.exit(main())
