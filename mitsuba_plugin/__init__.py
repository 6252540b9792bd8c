"""Mitsuba 3 plugins for sparse-brdf: the BSDFs ``sparse_brdf`` (the sparse model),
``sparse_library`` (many sparse materials in one BSDF, picked per shape),
``tabulated_brdf`` (a measured table, the reference) and ``neural_brdf`` (a Neural-BRDF
network), single-sided glossy reflectors for every variant's colours.

Usage::

    import mitsuba as mi
    import mitsuba_plugin

    mi.set_variant("llvm_ad_rgb")
    mitsuba_plugin.register()          # once per variant, before loading a scene
    bsdf = mi.load_dict({"type": "sparse_brdf", "filename": "gold.sbrdf"})

One job per module, each building on those before it:

- :mod:`~mitsuba_plugin.kernels`: lookup, sampling and colour building blocks;
- :mod:`~mitsuba_plugin.loading`: properties, files, the ensemble cache;
- :mod:`~mitsuba_plugin.decoders`: the sparse model's decoder kernels, and the
  ensembles' atom rows that every strict-decoded material shares;
- :mod:`~mitsuba_plugin.budget`: a scene's memory budget, which decoder each ``auto``
  material gets (:func:`memory_budget`, :func:`resolve`);
- :mod:`~mitsuba_plugin.glossy`: the BSDFs' shared base (sampling, pdf, colours);
- :mod:`~mitsuba_plugin.tabulated`, :mod:`~mitsuba_plugin.sparse`,
  :mod:`~mitsuba_plugin.neural`, :mod:`~mitsuba_plugin.library`: one BSDF each, its
  parameters in its class docstring
  (the choices: :data:`DECODERS`, :data:`LAYOUTS`, :data:`LOBES`,
  the importance-sampling strategies);
- :mod:`~mitsuba_plugin.registration`: the variants' classes, and :func:`register`;
- :mod:`~mitsuba_plugin.evaluators`: the baseline models' evaluators (the speed axis).

A missing or corrupt file fails at scene load with a :class:`PluginError` naming the
plugin and the file. Every loaded BSDF exposes ``memory_bytes`` (bytes of the arrays it
holds).
"""

from __future__ import annotations

from sparse_brdf.decoders.layouts import DECODERS, LAYOUTS, LOBES
from sparse_brdf.errors import PluginError

from .budget import memory_budget, resolve
from .library import check_scene
from .loading import load_ensemble
from .registration import classes, make_classes, register

__all__ = ["register", "classes", "make_classes", "PluginError", "DECODERS", "LAYOUTS",
           "LOBES", "load_ensemble", "memory_budget", "resolve", "check_scene"]
