"""The ``sparse-brdf`` command line. Each subcommand is a thin wrapper of a library call.

Private modules, one job each: ``_entry`` (``main``: one command run, its errors as one
line and an exit status), ``_process`` (the process's memory settings), ``_parser`` (the
parser, its help layout and one-line usage errors), ``_options`` (option declarations,
output kinds and the options several commands share), and the commands by family:
``_data`` (``corpus list``, ``info``, ``convert``), ``_train``, ``_codec`` (``encode``,
``decode``, ``blend``), ``_samples`` (``encode-samples``, ``plan-samples``), ``_render``
(``render``, ``snr``), ``_fit`` (``fit-scene``, ``fit-images``) and ``_bench``
(``bench``, ``bench-merge``). Each command checks its options at its entry and calls one
library function.
"""

from __future__ import annotations

from ._entry import EXIT_BUG, main
from ._options import COEFFS
from ._parser import EPILOG, build_parser, parsers
from ._process import MALLOC_SETTINGS

__all__ = ["COEFFS", "EPILOG", "EXIT_BUG", "MALLOC_SETTINGS", "build_parser", "main", "parsers"]
