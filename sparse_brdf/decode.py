"""Decoding coefficient files back to tabulated BRDFs."""

from __future__ import annotations

import os

from .brdf import BRDF
from .ensemble import Ensemble
from .sbrdf import load_sbrdf


def decode_file(path: str | os.PathLike, ensemble: Ensemble | None = None) -> BRDF:
    """Load a ``.sbrdf`` file and decode the full tensor (default: the shipped ensemble)."""
    ens = Ensemble.default() if ensemble is None else ensemble
    brdf = load_sbrdf(path, ens).decode(ens)
    brdf.source = os.fspath(path)
    return brdf
