"""Old module paths, kept importable for one release with a :class:`DeprecationWarning`.

The package's modules were grouped into packages named for their families (coding,
training, acquisition, compared, decoders, fitting; ``docs/architecture.md``). :data:`MOVED`
is the one table of old dotted names and the modules that now hold their code; a finder
on ``sys.meta_path`` (installed by ``sparse_brdf/__init__.py``) answers an old name with
the new module object itself, so ``import sparse_brdf.model.encode`` and
``from sparse_brdf.model import encode`` give the same module (and the same functions) as
``sparse_brdf.coding.encode``. Each old name warns once, on its first import.

Names that left a module that stays (the encoder's search for ``coding/projection.py``,
the render helpers' scenes and images for ``evaluation/scenes.py`` and ``images.py``, ...)
are answered the same way by that module's ``__getattr__`` (:data:`MOVED_NAMES`,
:func:`moved_names`).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import types
import warnings

#: Old module -> new module. ``sparse_brdf.model`` itself was only a folder; it is
#: answered by an empty package whose submodules are the old names below.
MOVED: dict[str, str] = {
    "sparse_brdf.model.tensor": "sparse_brdf.coding.tensor",
    "sparse_brdf.model.pruning": "sparse_brdf.coding.pruning",
    "sparse_brdf.model.ensemble": "sparse_brdf.coding.ensemble",
    "sparse_brdf.model.encode": "sparse_brdf.coding.encode",
    "sparse_brdf.model.budget": "sparse_brdf.coding.budget",
    "sparse_brdf.model.sparse": "sparse_brdf.coding.coefficients",
    "sparse_brdf.model.sbrdf": "sparse_brdf.coding.fileformat",
    "sparse_brdf.model.interpolate": "sparse_brdf.coding.interpolate",
    "sparse_brdf.model.train": "sparse_brdf.training.train",
    "sparse_brdf.model.shards": "sparse_brdf.training._shards",
    "sparse_brdf.model.tensor_store": "sparse_brdf.training._tensor_store",
    "sparse_brdf.model.checkpoint": "sparse_brdf.training._checkpoint",
    "sparse_brdf.samples": "sparse_brdf.acquisition.measurements",
    "sparse_brdf.sources.samples": "sparse_brdf.acquisition.files",
    "sparse_brdf.model.sampling": "sparse_brdf.acquisition.sensing",
    "sparse_brdf.model.acquire": "sparse_brdf.acquisition.recovery",
    "sparse_brdf.model.acquire_pool": "sparse_brdf.acquisition._pools",
    "sparse_brdf.model.acquire_pca": "sparse_brdf.acquisition.pca",
    "sparse_brdf.model.prior": "sparse_brdf.acquisition.prior",
    "sparse_brdf.evaluation.acquisition": "sparse_brdf.acquisition",
    "sparse_brdf.model.protocol": "sparse_brdf.compared.protocol",
    "sparse_brdf.model.compact": "sparse_brdf.compared.compact",
    "sparse_brdf.model.sparse_model": "sparse_brdf.compared.sparse_model",
    "sparse_brdf.model.baselines": "sparse_brdf.compared.baselines",
    "sparse_brdf.model.neural": "sparse_brdf.compared.neural",
    "sparse_brdf.model.specs": "sparse_brdf.compared.specs",
    "sparse_brdf.model.outside": "sparse_brdf.compared._outside",
    "sparse_brdf.model.layouts": "sparse_brdf.decoders.layouts",
    "sparse_brdf.model.lookups": "sparse_brdf.decoders.lookups",
    "sparse_brdf.evaluation.fit_images": "sparse_brdf.fitting.fit_images",
    "sparse_brdf.evaluation.fit_scene": "sparse_brdf.fitting.fit_scene",
    "sparse_brdf.evaluation.batch": "sparse_brdf.cli.files",
}
#: Old packages that no longer exist: answered by an empty package.
OLD_PACKAGES = ("sparse_brdf.model",)
#: Modules that stay, some of whose names moved to modules of their own: module -> where
#: the names went (each of these modules sets ``__getattr__ = moved_names(__name__)``).
MOVED_NAMES: dict[str, tuple[str, ...]] = {
    "sparse_brdf.coding.encode": ("sparse_brdf.coding.projection", "sparse_brdf.coding.fill"),
    "sparse_brdf.training.train": ("sparse_brdf.training._codes",),
    "sparse_brdf.decoders.layouts": ("sparse_brdf.decoders.buffers",),
    "sparse_brdf.evaluation.render": ("sparse_brdf.evaluation.scenes",
                                      "sparse_brdf.evaluation.images"),
    "sparse_brdf.fitting.fit_images": ("sparse_brdf.fitting._steps",),
}


def _importer() -> tuple[str, int, str, dict]:
    """File, line, module name and globals of the first frame outside the import
    machinery and this module: the code whose import named an old path."""
    frame = sys._getframe(1)
    while frame is not None:
        name = frame.f_code.co_filename
        if "importlib" not in name and "_bootstrap" not in name and name != __file__:
            g = frame.f_globals
            spec = g.get("__spec__")  # `python -m pkg.mod` runs as __main__; name the module
            return name, frame.f_lineno, getattr(spec, "name", None) or g.get("__name__", ""), g
        frame = frame.f_back
    return "sys", 1, "sys", {}


def _warn(old: str, new: str | None) -> None:
    where = f"; use {new}" if new else " (its modules moved; see sparse_brdf._moved.MOVED)"
    filename, lineno, module, g = _importer()
    warnings.warn_explicit(f"{old} is deprecated and will be removed in the next release{where}",
                           DeprecationWarning, filename, lineno, module=module,
                           registry=g.setdefault("__warningregistry__", {}) if g else None)


def moved_names(module: str):
    """The ``__getattr__`` of ``module``, some of whose names moved (:data:`MOVED_NAMES`):
    a name it no longer holds is looked up where its names went, in turn (the same
    object), with a :class:`DeprecationWarning` naming where it is now."""

    def __getattr__(name: str):
        if not name.startswith("__"):
            for home in MOVED_NAMES[module]:
                found = vars(importlib.import_module(home))
                if name in found:
                    _warn(f"{module}.{name}", f"{home}.{name}")
                    return found[name]
        raise AttributeError(f"module {module!r} has no attribute {name!r}")

    return __getattr__


class _Alias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Answers an old dotted name with the module that holds its code now."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname not in MOVED and fullname not in OLD_PACKAGES:
            return None
        return importlib.machinery.ModuleSpec(fullname, self,
                                              is_package=fullname in OLD_PACKAGES)

    def create_module(self, spec):
        if spec.name in OLD_PACKAGES:
            _warn(spec.name, None)
            module = types.ModuleType(spec.name, f"Deprecated: {spec.name} moved "
                                      "(see sparse_brdf._moved.MOVED).")
            module.__path__ = []
            return module
        new = MOVED[spec.name]
        _warn(spec.name, new)
        return importlib.import_module(new)

    def exec_module(self, module):
        pass


def install() -> None:
    """Put the finder first on ``sys.meta_path`` (once): before the path finders, so that a
    stale folder left by an old checkout cannot answer an old name."""
    if not any(isinstance(f, _Alias) for f in sys.meta_path):
        sys.meta_path.insert(0, _Alias())
