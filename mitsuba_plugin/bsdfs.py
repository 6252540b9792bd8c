"""Deprecated: the BSDFs now live one per module (see :mod:`mitsuba_plugin`). This module
re-exports the names it held, for one release, and warns on import."""

from __future__ import annotations

import warnings

from sparse_brdf.decoders.layouts import DECODERS, LAYOUTS, SAMPLING
from sparse_brdf.errors import PluginError

from .decoders import (
    GroupedBuffers,
    StrictBuffers,
    grouped_x,
    strict_x,
    upload_grouped,
    upload_strict,
)
from .glossy import GlossyBSDF
from .loading import load_ensemble
from .neural import NeuralBRDF
from .registration import (
    VARIANT_KINDS,
    classes,
    make_classes,
    register,
    srgb_coeff_path,
    variant_kind,
)
from .sparse import SparseBSDF
from .tabulated import TabulatedBRDF

warnings.warn("mitsuba_plugin.bsdfs is deprecated and will be removed in the next release: "
              "import from mitsuba_plugin (register, classes, make_classes) or its modules "
              "(registration, tabulated, sparse, neural, glossy, decoders, loading)",
              DeprecationWarning, stacklevel=2)

__all__ = ["DECODERS", "LAYOUTS", "SAMPLING", "PluginError", "load_ensemble",
           "GroupedBuffers", "upload_grouped", "grouped_x", "StrictBuffers", "upload_strict",
           "strict_x", "GlossyBSDF", "TabulatedBRDF", "SparseBSDF", "NeuralBRDF",
           "VARIANT_KINDS", "variant_kind", "srgb_coeff_path", "make_classes", "classes",
           "register"]
