"""One entry point that loads a BRDF from any supported source."""

from __future__ import annotations

import os
from pathlib import Path

from ..brdf import BRDF
from ..coords import MERL_SHAPE
from ..errors import BRDFFileError
from ..fileio import require_file
from .cache import cached_brdf, content_key

SUFFIXES = (".binary", ".h5", ".sbrdf")


def load_brdf(
    source: str | os.PathLike | dict,
    shape: tuple[int, int, int] = MERL_SHAPE,
    cache: bool = True,
) -> BRDF:
    """Load a BRDF on the grid ``shape``.

    ``source`` is a MERL/DTU ``.binary`` file, a Neural-BRDF ``.h5`` file (tabulated,
    cached), a ``.sbrdf`` coefficient file (decoded with the default ensemble),
    ``"mitsuba:<name>"`` for a built-in material, or a ``mi.load_dict`` dictionary.
    """
    if isinstance(source, dict):
        from .analytic import tabulate_mitsuba

        name = str(source.get("type", "mitsuba"))
        key = content_key("mitsuba-dict", source, list(shape), _mitsuba_version())
        return cached_brdf(key, lambda: tabulate_mitsuba(source, name, shape), cache)
    s = os.fspath(source)
    if s.startswith("mitsuba:"):
        from .analytic import tabulate_mitsuba
        from .corpora import mitsuba_catalog

        name = s.split(":", 1)[1]
        catalog = mitsuba_catalog()
        if name not in catalog:
            raise KeyError(f"{s}: no built-in material of that name (see `sparse-brdf corpus "
                           "list mitsuba`)")
        key = content_key("mitsuba", catalog[name], list(shape), _mitsuba_version())
        return cached_brdf(key, lambda: tabulate_mitsuba(catalog[name], name, shape), cache)
    path = Path(s)
    suffix = path.suffix.lower()
    if suffix == ".binary":
        from .merl import read_merl

        return read_merl(path)
    if suffix == ".h5":
        from .nbrdf import tabulate_nbrdf

        data = require_file(path, "Neural-BRDF file").read_bytes()
        key = content_key("nbrdf", data, list(shape))
        return cached_brdf(key, lambda: tabulate_nbrdf(path, shape), cache)
    if suffix == ".sbrdf":
        from ..model.sbrdf import decode_file

        return decode_file(path)
    require_file(path)
    raise BRDFFileError(f"{path}: unknown BRDF format (expected one of {', '.join(SUFFIXES)})")


def _mitsuba_version() -> str:
    import mitsuba as mi

    return mi.__version__
