"""What the plugins read: their scene properties, their files, and the ensemble cache.

Every property a BSDF knows is read with its default (Mitsuba rejects a scene whose
properties are left unread), names are checked against their declared choices, and a
file or ensemble that cannot be loaded fails at scene load with one
:class:`~sparse_brdf.errors.PluginError` naming the plugin and the file. Ensembles are
cached (one in memory at a time), so the scenes of a render or a fit share one.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

from sparse_brdf.coding.ensemble import resolve_ensemble
from sparse_brdf.coding.fileformat import decode_file, load_sbrdf
from sparse_brdf.errors import PluginError
from sparse_brdf.sources.load import load_brdf

_ENSEMBLES: dict = {}
_ENSEMBLE_LOCK = threading.Lock()


def load_ensemble(path: str | None, for_id: str | None = None):
    """The ensemble at ``path`` (None: the shipped one with id ``for_id``, or the shipped
    default), cached by path, size and mtime."""
    if path is None:
        key = ("<shipped>", for_id)
    else:
        st = os.stat(path)
        key = (os.path.realpath(path), st.st_size, st.st_mtime_ns)
    with _ENSEMBLE_LOCK:
        ens = _ENSEMBLES.get(key)
        if ens is None:
            ens = resolve_ensemble(path, for_id=for_id)
            _ENSEMBLES.clear()  # keep one ensemble in memory
            _ENSEMBLES[key] = ens
    return ens


def resolve_file(filename: str) -> str:
    """Resolve a scene-relative file name with Mitsuba's file resolver. An absolute name
    (as :func:`sparse_brdf.evaluation.scenes.scene_xml` writes every material's) is
    already resolved and a ``mitsuba:`` name needs none: both are returned as given."""
    if filename.startswith("mitsuba:") or os.path.isabs(filename):
        return filename
    import mitsuba as mi  # lazy: `import mitsuba_plugin` does not load Mitsuba

    try:
        return str(mi.file_resolver().resolve(filename))
    except Exception:  # noqa: BLE001 - fall back to the name as given
        return filename


#: The default of a property a scene must set (:func:`read_props`).
REQUIRED = object()


def read_props(props, plugin: str, spec: dict) -> dict:
    """Read every known property (Mitsuba rejects unread ones) with its default."""
    out = {}
    for name, default in spec.items():
        if name in props:
            out[name] = props.get(name)
        elif default is REQUIRED:
            raise PluginError(f"{plugin}: the parameter {name!r} is required")
        else:
            out[name] = default
    return out



def bool_prop(v, plugin: str, name: str) -> bool:
    """Property ``name`` of ``plugin`` as a boolean (a bool, or true/false, 1/0, yes/no,
    on/off in any case); anything else: a :class:`PluginError` naming it."""
    if isinstance(v, bool):
        return v
    s = str(v).strip().lower()
    if s in ("true", "1", "yes", "on"):
        return True
    if s in ("false", "0", "no", "off"):
        return False
    raise PluginError(f"{plugin}: {name}={v!r} is not a boolean")


def choice_prop(v, allowed, plugin: str, name: str) -> str:
    """Property ``name`` of ``plugin`` as one of ``allowed``; anything else: a
    :class:`PluginError` naming it and the choices."""
    s = str(v)
    if s not in allowed:
        raise PluginError(f"{plugin}: {name}={s!r}: expected one of {', '.join(allowed)}")
    return s


def load_table(filename: str, ensemble, plugin: str):
    """The :class:`~sparse_brdf.brdf.BRDF` in ``filename`` (a ``.sbrdf`` file decoded with
    the ``ensemble`` path if given); a :class:`PluginError` naming the plugin and file."""
    try:
        if ensemble is not None and Path(filename).suffix.lower() == ".sbrdf":
            return decode_file(filename, load_ensemble(resolve_file(str(ensemble))))
        return load_brdf(filename)
    except Exception as exc:  # noqa: BLE001 - re-raised with the plugin and file named
        raise PluginError(f"{plugin}: cannot load {filename!r}: {exc}") from exc


def load_model(filename: str, ens_path: str | None, plugin: str):
    """(model, ensemble) of the ``.sbrdf`` file ``filename``, checked against each other:
    the ensemble at ``ens_path`` or the shipped one the file names; any failure: a
    :class:`PluginError` naming the plugin and the file."""
    try:
        model = load_sbrdf(filename)
    except Exception as exc:  # noqa: BLE001
        raise PluginError(f"{plugin}: cannot load {filename!r}: {exc}") from exc
    try:
        ens = load_ensemble(ens_path, model.ensemble_id)
    except Exception as exc:  # noqa: BLE001
        what = "the shipped ensemble" if ens_path is None else repr(ens_path)
        raise PluginError(f"{plugin}: cannot load {what} for {filename!r}: {exc}") from exc
    try:  # the id, the dictionary indices and the grid
        model.check_ensemble(ens)
    except Exception as exc:  # noqa: BLE001
        raise PluginError(f"{plugin}: cannot load {filename!r}: {exc}") from exc
    return model, ens


def split_names(value: str) -> list[str]:
    """The file names of a list property: separated by commas (or new lines), each
    stripped of surrounding spaces; empty names dropped."""
    return [n.strip() for n in str(value).replace("\n", ",").split(",") if n.strip()]


def load_models(filenames, ens_path: str | None, plugin: str):
    """(models, ensemble) of the ``.sbrdf`` files ``filenames``, all of one ensemble and
    one grid: the ensemble at ``ens_path`` or the shipped one the first file names. A
    file that cannot be loaded, or of another ensemble or grid than the first: a
    :class:`PluginError` naming the plugin and the file."""
    if not filenames:
        raise PluginError(f"{plugin}: the parameter 'filenames' names no file")
    first, ens = load_model(filenames[0], ens_path, plugin)
    models = [first]
    for f in filenames[1:]:
        try:
            model = load_sbrdf(f)
        except Exception as exc:  # noqa: BLE001
            raise PluginError(f"{plugin}: cannot load {f!r}: {exc}") from exc
        if ens_path is None and model.ensemble_id != first.ensemble_id:
            raise PluginError(f"{plugin}: {f!r} was encoded with ensemble "
                              f"{model.ensemble_id[:12]}, {filenames[0]!r} with "
                              f"{first.ensemble_id[:12]}: a library holds the materials of "
                              f"one ensemble")
        if tuple(model.shape) != tuple(first.shape):
            raise PluginError(f"{plugin}: {f!r} is on the grid {tuple(model.shape)}, "
                              f"{filenames[0]!r} on {tuple(first.shape)}: a library holds "
                              f"the materials of one grid")
        try:
            model.check_ensemble(ens)
        except Exception as exc:  # noqa: BLE001
            raise PluginError(f"{plugin}: cannot load {f!r}: {exc}") from exc
        models.append(model)
    return models, ens


def library_key(filename) -> tuple:
    """(ensemble id, grid) of the ``.sbrdf`` file ``filename``: what the materials of one
    ``sparse_library`` share (:func:`load_models`)."""
    model = load_sbrdf(filename)
    return model.ensemble_id, tuple(model.shape)
