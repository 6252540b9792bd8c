"""Mitsuba 3 plugins for sparse-brdf: ``sparse_brdf`` (the model), ``tabulated_brdf`` and
``neural_brdf`` (a Neural-BRDF network).

Usage::

    import mitsuba as mi
    import mitsuba_plugin

    mi.set_variant("llvm_ad_rgb")
    mitsuba_plugin.register()          # once per variant, before loading a scene
    bsdf = mi.load_dict({"type": "sparse_brdf", "filename": "gold.sbrdf"})

The BSDFs are single-sided glossy reflectors (``GlossyReflection | FrontSide``), share
the same sampling code and every variant's colours (rgb, mono, spectral, polarized),
the two tabulated ones the bin lookup of docs/method.md ("Grid, lookup convention,
validity"), and return ``BSDF * cos(theta_o)`` from ``eval``. Parameters:

``sparse_brdf``
    ``filename`` (.sbrdf), ``ensemble`` (optional .npz, default the shipped one),
    ``decoder`` ("grouped" | "strict" | "auto"), ``layout`` ("auto" | "union" |
    "slots", for the grouped decoder), ``sampling`` ("cosine" | "lobe"), ``interpolate``
    (bool). The name lists are :data:`DECODERS`, :data:`LAYOUTS` and :data:`SAMPLING`,
    defined in :mod:`sparse_brdf.model.layouts`.
``tabulated_brdf``
    ``filename`` (anything :func:`sparse_brdf.sources.load.load_brdf` reads), ``sampling``,
    ``interpolate``, ``ensemble`` (for decoding a .sbrdf file).
``neural_brdf``
    ``filename`` (a Neural-BRDF Keras ``.h5`` network), ``sampling``; evaluated at the
    direction pair itself by the same kernel as the ``nbrdf`` evaluator.

A missing or corrupt file fails at scene load with a :class:`PluginError` naming the
plugin and the file. The loaded objects expose ``memory_bytes`` (bytes of the arrays
they hold) and, for ``sparse_brdf``, ``decoder``, ``n_terms``, ``distinct_atoms`` and
``basis`` (the file's colour basis: "rgb", or "opponent", whose coded channels the kernel
mixes back to R, G, B).

The package holds only Dr.Jit/Mitsuba code: :mod:`~mitsuba_plugin.bsdfs` (the BSDFs,
their decoder kernels and registration), :mod:`~mitsuba_plugin.kernels` (the shared
lookup and sampling building blocks) and :mod:`~mitsuba_plugin.evaluators` (Dr.Jit
evaluators of the baseline models). The per-material numpy data comes from
:mod:`sparse_brdf.model.layouts`.
"""

from __future__ import annotations

from .bsdfs import (
    DECODERS,
    LAYOUTS,
    SAMPLING,
    PluginError,
    classes,
    load_ensemble,
    make_classes,
    register,
)

__all__ = ["register", "classes", "make_classes", "PluginError", "DECODERS", "LAYOUTS",
           "SAMPLING", "load_ensemble"]
