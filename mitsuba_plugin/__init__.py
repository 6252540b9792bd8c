"""Mitsuba 3 plugins for sparse-brdf: ``sparse_brdf`` (the model) and ``tabulated_brdf``.

Usage::

    import mitsuba as mi
    import mitsuba_plugin

    mi.set_variant("llvm_ad_rgb")
    mitsuba_plugin.register()          # once per variant, before loading a scene
    bsdf = mi.load_dict({"type": "sparse_brdf", "filename": "gold.sbrdf"})

Both BSDFs are single-sided glossy reflectors (``GlossyReflection | FrontSide``), share
the bin lookup of SPEC section 1 and the same sampling code, and return
``BSDF * cos(theta_o)`` from ``eval``. Parameters:

``sparse_brdf``
    ``filename`` (.sbrdf), ``ensemble`` (optional .npz, default the shipped one),
    ``decoder`` ("grouped" | "strict" | "auto"), ``sampling`` ("cosine" | "lobe"),
    ``interpolate`` (bool).
``tabulated_brdf``
    ``filename`` (anything :func:`sparse_brdf.sources.load.load_brdf` reads), ``sampling``,
    ``interpolate``, ``ensemble`` (for decoding a .sbrdf file).

A missing or corrupt file fails at scene load with a :class:`PluginError` naming the
plugin and the file. The loaded objects expose ``memory_bytes`` (bytes of the arrays
they hold) and, for ``sparse_brdf``, ``decoder``, ``n_terms`` and ``distinct_atoms``.
"""

from __future__ import annotations

from .bsdfs import DECODERS, SAMPLING, PluginError, load_ensemble, make_classes

__all__ = ["register", "classes", "PluginError", "DECODERS", "SAMPLING", "load_ensemble"]

_CLASSES: dict[str, tuple[type, type]] = {}


def classes(variant: str | None = None) -> tuple[type, type]:
    """(TabulatedBRDF, SparseBSDF) classes of ``variant`` (default: the current one)."""
    import mitsuba as mi

    name = variant or mi.variant()
    if name is None:
        raise RuntimeError("no Mitsuba variant is set: call mi.set_variant(...) first")
    if name not in _CLASSES:
        import importlib

        module = importlib.import_module(f"mitsuba.{name}")
        _CLASSES[name] = make_classes(module)
    return _CLASSES[name]


_REGISTERED: set[str] = set()


def register() -> str:
    """Register ``sparse_brdf`` and ``tabulated_brdf`` for the current variant.

    Idempotent per variant; returns the variant's name. Call after ``mi.set_variant``
    and before loading a scene that uses the plugins.
    """
    import mitsuba as mi

    name = mi.variant()
    if name is None:
        raise RuntimeError("no Mitsuba variant is set: call mi.set_variant(...) first")
    if name in _REGISTERED:
        return name
    tabulated, sparse = classes(name)
    mi.register_bsdf("tabulated_brdf", lambda props: tabulated(props))
    mi.register_bsdf("sparse_brdf", lambda props: sparse(props))
    _REGISTERED.add(name)
    return name
