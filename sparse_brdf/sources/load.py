"""One entry point that loads a BRDF from any supported source."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..coding.fileformat import decode_file
from ..coords import MERL_SHAPE
from ..errors import BRDFFileError, InvalidBRDFError, UnknownNameError
from ..fileio import require_file
from .analytic import tabulate_mitsuba
from .cache import cached_brdf, content_key
from .catalog import mitsuba_catalog
from .fits import FIT_MODELS, FITS_VERSION, material_parameters, tabulate_fit
from .merl import read_merl
from .nbrdf import tabulate_nbrdf

SUFFIXES = (".binary", ".h5", ".sbrdf")


def load_brdf(
    source: str | os.PathLike | dict,
    shape: tuple[int, int, int] = MERL_SHAPE,
    cache: bool = True,
    symmetrize: bool | None = None,
) -> BRDF:
    """Load a BRDF on the grid ``shape``.

    Parameters
    ----------
    source : str, path-like or dict
        A MERL/DTU ``.binary`` file (read on its own grid), a Neural-BRDF ``.h5`` file
        (tabulated on ``shape``), a ``.sbrdf`` coefficient file (decoded with the
        shipped ensemble the file names), ``"mitsuba:<name>"`` for one of
        Mitsuba's built-in materials (``sparse-brdf corpus list mitsuba``),
        ``"abc:<name>"`` or ``"sgd:<name>"`` for the ABC or SGD analytic fit of a MERL
        material (:mod:`sparse_brdf.sources.fits`; ``sparse-brdf corpus list abc``), or a
        ``mi.load_dict`` dictionary of a Mitsuba BSDF.
    shape : tuple of 3 int
        The (theta_h, theta_d, phi_d) grid for tabulated sources; default MERL's
        (90, 90, 180).
    cache : bool
        Keep tabulations (of networks, Mitsuba BSDFs and analytic fits) in the user
        cache, keyed by their content, and reuse them.
    symmetrize : bool, optional
        Average the values over the symmetries of an isotropic, reciprocal BRDF: the
        mirror phi_d -> -phi_d and reciprocity phi_d -> phi_d + pi. None (the default):
        True for a Neural-BRDF network (whose fits break reciprocity, by a median 24-30 %
        per bin for some RGL-EPFL materials; ``docs/method.md``, "Symmetric
        references"), False for every other source. True on a table (``.binary``,
        ``.sbrdf``, analytic) averages each phi_d bin with its mirror.

    Returns
    -------
    BRDF
        Linear-RGB values in 1/sr, shape (n1, n2, n3, 3).

    Raises
    ------
    MissingFileError
        If the file does not exist.
    BRDFFileError
        For an unknown suffix, or a file that is truncated, corrupt or decodes to
        unusable values.
    UnknownNameError
        For a ``mitsuba:`` name that is not a built-in material, or an ``abc:`` or
        ``sgd:`` name without a fit.
    MissingDataError
        For an ``abc:`` or ``sgd:`` source when the fits' parameter file is absent
        (``../shared/data/fits``).
    """
    brdf = _load(source, shape, cache, symmetrize is not False)
    if symmetrize and not brdf.meta.get("symmetric"):
        brdf = symmetrize_table(brdf)
    return brdf


def source_key(
    source: str | os.PathLike | dict,
    shape: tuple[int, int, int] = MERL_SHAPE,
    symmetrize: bool | None = None,
) -> str:
    """The sha256 (hex) of everything a tabulation of ``source`` reads: the exact inputs.

    A file's bytes (a network, a MERL table, a coefficient file), a Mitsuba BSDF's
    parameters with the Mitsuba version, an analytic fit's parameters; the grid; whether
    a network is symmetrised. Two sources with one key tabulate to the same values on
    one machine (the key of the tabulation cache). Arguments as :func:`load_brdf`.

    Returns
    -------
    str
        64 hex digits.

    Raises
    ------
    As :func:`load_brdf` for a missing file or an unknown name.
    """
    symmetric_network = symmetrize is not False
    if isinstance(source, dict):
        return content_key("mitsuba-dict", source, list(shape), _mitsuba_version())
    s = os.fspath(source)
    if s.startswith("mitsuba:"):
        return content_key("mitsuba", _catalog_entry(s), list(shape), _mitsuba_version())
    prefix, colon, name = s.partition(":")
    if colon and prefix in FIT_MODELS:
        params = material_parameters(prefix, name)
        return content_key("fit", FITS_VERSION, prefix, name,
                           {k: v.tolist() for k, v in params.items()}, list(shape))
    data = require_file(Path(s), "BRDF file").read_bytes()
    if s.lower().endswith(".h5"):
        return content_key("nbrdf", data, list(shape),
                           *(["symmetric"] if symmetric_network else []))
    return content_key("file", data, *(["symmetric"] if symmetrize else []))


def _catalog_entry(source: str) -> dict:
    """The Mitsuba BSDF of a ``mitsuba:<name>`` source."""
    name = source.split(":", 1)[1]
    catalog = mitsuba_catalog()
    if name not in catalog:
        raise UnknownNameError(f"{source}: no built-in material of that name (see "
                               "`sparse-brdf corpus list mitsuba`)")
    return catalog[name]


def _load(source, shape: tuple[int, int, int], cache: bool, symmetric_network: bool) -> BRDF:
    """:func:`load_brdf` without a table's symmetrisation; ``symmetric_network`` averages
    a network over its symmetries as it is tabulated."""
    if isinstance(source, dict):
        name = str(source.get("type", "mitsuba"))
        return cached_brdf(source_key(source, shape),
                           lambda: tabulate_mitsuba(source, name, shape), cache)
    s = os.fspath(source)
    if s.startswith("mitsuba:"):
        bsdf, name = _catalog_entry(s), s.split(":", 1)[1]
        return cached_brdf(source_key(s, shape),
                           lambda: tabulate_mitsuba(bsdf, name, shape), cache)
    prefix, colon, _ = s.partition(":")
    if colon and prefix in FIT_MODELS:
        model, name = s.split(":", 1)
        return cached_brdf(source_key(s, shape), lambda: tabulate_fit(model, name, shape),
                           cache)
    path = Path(s)
    suffix = path.suffix.lower()
    if suffix == ".binary":
        return read_merl(path)
    if suffix == ".h5":
        require_file(path, "Neural-BRDF file")
        key = source_key(path, shape, symmetric_network)
        brdf = cached_brdf(key, lambda: tabulate_nbrdf(path, shape, symmetric_network),
                           cache)
        brdf.meta["symmetric"] = symmetric_network
        # the key is the content; the name and path are those of the file asked for (a
        # byte-identical copy elsewhere must not take the cached file's name)
        brdf.name = path.name.removesuffix(path.suffix)
        brdf.source = os.fspath(path)
        return brdf
    if suffix == ".sbrdf":
        try:
            return decode_file(path)
        except InvalidBRDFError as exc:  # e.g. coefficients so large the values overflow
            raise BRDFFileError(f"{path}: decodes to unusable values: {exc}") from exc
    require_file(path)
    raise BRDFFileError(f"{path}: unknown BRDF format (expected one of {', '.join(SUFFIXES)})")


def symmetrize_table(brdf: BRDF) -> BRDF:
    """``brdf`` averaged with its mirror phi_d -> -phi_d.

    On the grid, whose phi_d is folded into [0, pi) by reciprocity, the mirror takes bin
    k (at k pi / n3) to bin (n3 - k) mod n3; the average is then unchanged by the mirror,
    and by reciprocity through the fold.

    Parameters
    ----------
    brdf : BRDF
        Values (n1, n2, n3, C).

    Returns
    -------
    BRDF
        A new BRDF, the same shape, name and source.
    """
    n3 = brdf.shape[2]
    mirror = (-np.arange(n3)) % n3
    values = 0.5 * (brdf.values + brdf.values[:, :, mirror])
    valid = brdf.valid & brdf.valid[:, :, mirror]
    values = np.where(valid[..., None], values, 0).astype(np.float32)
    return BRDF(values=values, valid=valid, name=brdf.name, source=brdf.source,
                meta={**brdf.meta, "symmetric": True})


def _mitsuba_version() -> str:
    import mitsuba as mi  # lazy: Mitsuba is slow to import and only needed for mitsuba: sources

    return mi.__version__
