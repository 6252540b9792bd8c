"""Registering the BSDFs with Mitsuba: the classes of one variant, and :func:`register`.

A Python BSDF must derive from the variant's ``mi.BSDF``, so the BSDFs
(:class:`~mitsuba_plugin.tabulated.TabulatedBRDF`,
:class:`~mitsuba_plugin.sparse.SparseBSDF`, :class:`~mitsuba_plugin.neural.NeuralBRDF`,
:class:`~mitsuba_plugin.library.SparseLibrary`, on
:class:`~mitsuba_plugin.glossy.GlossyBSDF`) are written against no base and
:func:`make_classes` copies their bodies onto subclasses of one variant's ``mi.BSDF``,
with that variant's names and colour kind as class attributes; :func:`classes` caches
them per variant, and :func:`register`, at the end as in Mitsuba's own Python plugins,
registers ``tabulated_brdf``, ``sparse_brdf``, ``neural_brdf`` and ``sparse_library`` for
the current one.
"""

from __future__ import annotations

import importlib
import threading
from pathlib import Path

from sparse_brdf.errors import PluginError

from .glossy import GlossyBSDF
from .kernels import Ops, SpectralUpsampling, VariantNamespace
from .library import SparseLibrary
from .neural import NeuralBRDF
from .sparse import SparseBSDF
from .tabulated import TabulatedBRDF


def _derive(blueprint: type, base: type, **attrs) -> type:
    """A subclass of ``base`` with the body (methods, docstring) of ``blueprint``."""
    body = {k: v for k, v in vars(blueprint).items() if k not in ("__dict__", "__weakref__")}
    return type(blueprint.__name__, (base,), {**body, **attrs})


#: What each kind of variant returns from ``eval``: its colour representation.
VARIANT_KINDS = ("rgb", "mono", "spectral")


def variant_kind(name: str) -> tuple[str, bool]:
    """(colour kind, polarized) of the Mitsuba variant ``name``, e.g.
    ``("spectral", True)`` for ``llvm_ad_spectral_polarized``; a :class:`PluginError`
    naming the variant if the plugin cannot render in it."""
    parts = name.split("_")
    kinds = [k for k in VARIANT_KINDS if k in parts]
    if len(kinds) != 1 or (parts[0] not in ("scalar", "llvm", "cuda")):
        raise PluginError(f"mitsuba_plugin: the Mitsuba variant {name!r} is not supported "
                          f"(expected a scalar, llvm or cuda variant of "
                          f"{', '.join(VARIANT_KINDS)} colours)")
    return kinds[0], "polarized" in parts


def srgb_coeff_path() -> Path:
    """Mitsuba's RGB-to-spectrum table, ``data/srgb.coeff`` (Mitsuba's file resolver,
    else the installed package's folder)."""
    import mitsuba as mi  # lazy: `import mitsuba_plugin` does not load Mitsuba

    try:
        p = Path(str(mi.file_resolver().resolve("data/srgb.coeff")))
        if p.is_file():
            return p
    except Exception:  # noqa: BLE001 - fall back to the package folder
        pass
    return Path(mi.__file__).parent / "data" / "srgb.coeff"


def _upsampling_loader(name: str, ops: Ops):
    """A function returning the variant's :class:`SpectralUpsampling`, read once."""
    box: list = []
    lock = threading.Lock()

    def get(_self=None):
        with lock:
            if not box:
                path = srgb_coeff_path()
                try:
                    box.append(SpectralUpsampling(ops, path))
                except (OSError, ValueError) as exc:
                    raise PluginError(f"mitsuba_plugin: variant {name}: cannot read "
                                      f"Mitsuba's spectral upsampling table {path}: "
                                      f"{exc}") from exc
        return box[0]

    return get


def make_classes(module, name: str | None = None) -> tuple[type, type, type, type]:
    """(TabulatedBRDF, SparseBSDF, NeuralBRDF, SparseLibrary) of variant module ``module`` (e.g.
    ``mitsuba.llvm_ad_rgb``, whose variant is ``name``, default: the module's own name):
    the BSDFs' classes on that variant's ``mi.BSDF``."""
    m = VariantNamespace(module)
    name = name or m.name
    kind, polarized = variant_kind(name)
    ops = Ops(m)
    flags = m.BSDFFlags.GlossyReflection | m.BSDFFlags.FrontSide
    base = _derive(GlossyBSDF, m.BSDF, _m=m, _ops=ops, _flags=flags,
                   _glossy=int(+m.BSDFFlags.GlossyReflection), _zero3=m.Color3f(0.0),
                   _zero_s=m.UnpolarizedSpectrum(0.0), _kind=kind, _polarized=polarized,
                   _upsampling=_upsampling_loader(name, ops))
    return (_derive(TabulatedBRDF, base), _derive(SparseBSDF, base), _derive(NeuralBRDF, base),
            _derive(SparseLibrary, base))


_CLASSES: dict[str, tuple[type, type, type, type]] = {}
_REGISTERED: set[str] = set()


def _current_variant(variant: str | None = None) -> str:
    import mitsuba as mi  # lazy: `import mitsuba_plugin` does not load Mitsuba

    name = variant or mi.variant()
    if name is None:
        raise PluginError("mitsuba_plugin: no Mitsuba variant is set: call "
                          "mi.set_variant(...) first")
    return name


def classes(variant: str | None = None) -> tuple[type, type, type, type]:
    """(TabulatedBRDF, SparseBSDF, NeuralBRDF, SparseLibrary) classes of ``variant``
    (default: the current one)."""
    name = _current_variant(variant)
    if name not in _CLASSES:
        variant_kind(name)  # an unsupported variant: one line naming it
        try:
            module = importlib.import_module(f"mitsuba.{name}")
        except ImportError as exc:
            raise PluginError(f"mitsuba_plugin: the Mitsuba variant {name!r} is not "
                              f"available in this installation: {exc}") from exc
        _CLASSES[name] = make_classes(module, name)
    return _CLASSES[name]


def register() -> str:
    """Register ``sparse_brdf``, ``tabulated_brdf``, ``neural_brdf`` and
    ``sparse_library`` for the current variant.

    Idempotent per variant; returns the variant's name. Call after ``mi.set_variant``
    and before loading a scene that uses the plugins.
    """
    import mitsuba as mi  # lazy: `import mitsuba_plugin` does not load Mitsuba

    name = _current_variant()
    if name in _REGISTERED:
        return name
    tabulated, sparse, neural, library = classes(name)
    mi.register_bsdf("tabulated_brdf", lambda props: tabulated(props))
    mi.register_bsdf("sparse_brdf", lambda props: sparse(props))
    mi.register_bsdf("neural_brdf", lambda props: neural(props))
    mi.register_bsdf("sparse_library", lambda props: library(props))
    _REGISTERED.add(name)
    return name
