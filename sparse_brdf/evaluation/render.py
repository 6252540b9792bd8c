"""Rendering helpers: scenes with overridable materials, images, masks, the noise floor.

Any Mitsuba 3 scene file names its materials by id; :func:`render_scene` replaces each
overridden id by ``sparse_brdf`` (for a ``.sbrdf`` file) or ``tabulated_brdf`` (any other
source :func:`sparse_brdf.sources.load.load_brdf` reads) and renders with Mitsuba 3. The
scene's ``$``-parameters get values only where it declares them (``<default>``, as the
shipped ``scenes/`` declare ``spp``, ``res`` and ``seed``); otherwise spp and seed are set
on its first sensor's sampler and the resolution on its film (aspect ratio kept).
:func:`object_mask` gives the pixels of the object-only SNR: those whose camera rays first
hit a shape carrying one of the replaced materials. Images are written by suffix
(:func:`write_image`: ``.exr`` linear, ``.png``/``.jpg`` an sRGB preview). Errors raised
inside a render surface as "drjit.custom ... (see above)"; :class:`RenderError` carries
the real message from the ``__cause__`` chain (``docs/method.md``, "Rendering with
Mitsuba").

Mitsuba, Dr.Jit and :mod:`mitsuba_plugin` are imported inside the functions that render,
so that ``import sparse_brdf`` and ``sparse-brdf --help`` never load them.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..errors import (
    ImageFileError,
    MissingDataError,
    MissingFileError,
    OutputError,
    RenderError,
    SceneError,
    SparseBRDFError,
    UnknownNameError,
    UsageError,
)
from ..fileio import atomic_path, atomic_write, require_file
from ..metrics import SNRForms, snr_forms
from ..mitsuba_env import DEFAULT_VARIANT, set_variant
from ..model.layouts import SAMPLING
from ..params import SEED, Interval, check, check_choice
from ..paths import SCENES_DIR, shared_envmaps_dir

SPARSE_SUFFIX = ".sbrdf"
#: The spp, seed and res a render accepts (Mitsuba's seed is 32-bit; 0 spp crashes it).
RENDER_PARAMETERS = {"spp": Interval(int, 1, 1 << 16), "seed": SEED,
                     "res": Interval(int, 1, 1 << 13)}
#: The shipped scenes: ``sphere.xml`` (CC0 studio map), ``spheres.xml`` (three materials),
#: ``paper_sphere.xml`` (the paper's scene; needs the shared Grace Cathedral map).


def find_scene(name: str | os.PathLike) -> Path:
    """A scene file: ``name`` as a path if it exists, else the shipped scene of that name
    (``paper_sphere`` and ``paper_sphere.xml`` both work)."""
    p = Path(name)
    if p.is_file():
        return p
    for cand in (SCENES_DIR / p, SCENES_DIR / f"{p}.xml"):
        if cand.is_file():
            return cand
    shipped = ", ".join(sorted(q.stem for q in SCENES_DIR.glob("*.xml")))
    raise MissingFileError(f"{name}: no such scene file, and no shipped scene of that name "
                           f"(shipped: {shipped})")


_SEPARATORS = re.compile(r"[/\\]")


class SceneSpec(NamedTuple):
    """A scene as a bench names it: ``NAME[:KEY=VALUE[,KEY=VALUE...]]``, e.g.
    ``sphere_light.xml:lightangle=40`` (see :func:`parse_scene_spec`).

    Attributes
    ----------
    path : Path
        The scene file (:func:`find_scene`).
    params : dict of str to str
        Scene defaults set for every render of it (as ``-D KEY=VALUE`` would).
    key : str
        Its name in results and file names: the file's stem, then ``-KEY=VALUE`` per
        parameter in the order given (``sphere_light-lightangle=40``; a value's path
        separators as underscores).
    """

    path: Path
    params: dict
    key: str


def parse_scene_spec(text: str) -> SceneSpec:
    """Read a scene spec ``NAME[:KEY=VALUE[,KEY=VALUE...]]``: a scene file or shipped
    scene, then scene defaults to set (the ``<default>`` names the scene declares; spp,
    seed and res are the bench's own settings).

    Raises
    ------
    MissingFileError
        No such scene.
    UsageError
        A malformed parameter, one the scene does not declare, or spp/seed/res.
    """
    name, params = text, {}
    head, sep, tail = text.rpartition(":")
    if sep and head and not Path(text).is_file():
        name = head
        fixed = sorted({x.partition("=")[0].strip() for x in tail.split(",")}
                       & set(RENDER_PARAMETERS))
        if fixed:
            raise UsageError(f"scene {text!r}: {', '.join(fixed)} is set for every scene "
                             "(a setting of its own), not per scene")
        params = parse_defaults(filter(None, (x.strip() for x in tail.split(","))),
                                f"scene {text!r}:")
    path = find_scene(name)
    declared = {d.get("name") for d in parse_scene(path).getroot().iter("default")}
    unknown = sorted(set(params) - declared)
    if unknown:
        raise UsageError(f"scene {text!r}: {path.name} declares no parameter "
                         f"{', '.join(unknown)} (it has {', '.join(sorted(declared))})")
    # the key names folders and files: a value's path separators become underscores
    key = path.stem + "".join(f"-{k}={_SEPARATORS.sub('_', v)}" for k, v in params.items())
    return SceneSpec(path, params, key)


def parse_overrides(items: Iterable[str]) -> dict[str, str]:
    """``["id=FILE", ...]`` -> ``{"id": "FILE"}`` (a bare FILE means id "material")."""
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            key, value = "material", item
        key, value = key.strip(), value.strip()
        if not key or not value:
            raise UsageError(f"material override {item!r}: expected ID=FILE")
        out[key] = value
    return out


def parse_defaults(items: Iterable[str], option: str) -> dict[str, str]:
    """``["KEY=VALUE", ...]`` -> scene defaults ``{"KEY": "VALUE"}`` (e.g. ``envrot=90``).

    ``spp``, ``seed`` and ``res`` are refused: they have options of their own. A
    malformed item is a :class:`~sparse_brdf.errors.UsageError` naming ``option``."""
    out: dict[str, str] = {}
    for item in items:
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq or not key:
            raise UsageError(f"{option} {item!r}: expected KEY=VALUE (a scene default, e.g. "
                             "envrot=90)")
        if key in RENDER_PARAMETERS:
            raise UsageError(f"{option} {key}: use --{key}")
        out[key] = value.strip()
    return out


def plugin_for(source: str) -> str:
    """The plugin that renders ``source``: sparse_brdf for .sbrdf, else tabulated_brdf."""
    return "sparse_brdf" if str(source).lower().endswith(SPARSE_SUFFIX) else "tabulated_brdf"


def _cause_message(exc: BaseException) -> str:
    """The message of the innermost of our own errors in the ``__cause__`` chain of
    ``exc`` (e.g. a plugin's "cannot load FILE: ..."), which says all; else the messages
    of ``exc`` and its causes, innermost first, without repetitions."""
    chain: list[BaseException] = []
    e: BaseException | None = exc
    while e is not None and all(e is not c for c in chain):
        chain.append(e)
        e = e.__cause__ or e.__context__
    ours = [c for c in chain if isinstance(c, SparseBRDFError)]
    if ours:
        return str(ours[-1]).strip()
    parts: list[str] = []
    for c in chain:
        msg = _without_traceback(str(c))
        if msg and msg not in parts:
            parts.append(msg)
    return " <- ".join(reversed(parts)) if len(parts) > 1 else (parts[0] if parts else
                                                                type(exc).__name__)


def _without_traceback(msg: str) -> str:
    """A Mitsuba message without the Python traceback it may embed (a plugin's error
    raised during scene loading: only the exception's own message is kept) and without
    Mitsuba's source position and position in the generated XML string."""
    head, sep, tb = msg.partition("Traceback (most recent call last):")
    if sep:
        last = [ln.strip() for ln in tb.splitlines() if ln.strip()]
        tail = last[-1] if last else ""
        name, colon, rest = tail.partition(": ")
        head = head.rstrip() + " " + (rest if colon and name.isidentifier() else tail)
    head = re.sub(r"^\[[\w.]+:\d+\]\s*", "", head.strip())
    return re.sub(r"^At string \(line \d+, col \d+\):\s*", "", head).strip()


def parse_scene(scene_path: str | os.PathLike) -> ET.ElementTree:
    """A scene's XML tree; :class:`SceneError` naming the file if it is malformed."""
    try:
        return ET.parse(scene_path)
    except ET.ParseError as exc:
        raise SceneError(f"{scene_path}: not a valid scene XML file: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise SceneError(f"{scene_path}: not a valid scene XML file ({exc.reason})") from exc


def _abs_source(value: str, base: Path) -> str:
    if value.startswith("mitsuba:"):
        return value
    p = Path(value).expanduser()
    return str(p if p.is_absolute() else (Path.cwd() / p).resolve())


def scene_xml(
    scene_path: str | os.PathLike,
    materials: Mapping[str, str] | None = None,
    sparse_options: Mapping[str, object] | None = None,
    tabulated_options: Mapping[str, object] | None = None,
) -> str:
    """The scene's XML with the BSDFs of ``materials`` (id -> file) replaced.

    ``sparse_options``/``tabulated_options`` are extra plugin parameters (e.g.
    ``{"decoder": "strict", "ensemble": path}``), written as strings (booleans as
    ``<boolean>``). Relative material paths are taken from the current directory.
    """
    root = _replaced(scene_path, materials, sparse_options, tabulated_options)
    return ET.tostring(root, encoding="unicode")


def _replaced(scene_path, materials, sparse_options, tabulated_options) -> ET.Element:
    """The scene's XML root with the BSDFs of ``materials`` replaced (:func:`scene_xml`)."""
    scene_path = Path(scene_path)
    root = parse_scene(scene_path).getroot()
    for mid, source in (materials or {}).items():
        parent, elem = _find_by_id(root, mid)
        if elem is None:
            raise UnknownNameError(f"{scene_path}: no element with id {mid!r} to override "
                           f"(ids: {', '.join(sorted(_ids(root))) or 'none'})")
        plugin = plugin_for(source)
        new = ET.Element("bsdf", {"type": plugin, "id": mid})
        ET.SubElement(new, "string", {"name": "filename",
                                      "value": _abs_source(source, scene_path.parent)})
        opts = sparse_options if plugin == "sparse_brdf" else tabulated_options
        for key, val in (opts or {}).items():
            if isinstance(val, bool):
                ET.SubElement(new, "boolean", {"name": key, "value": str(val).lower()})
            else:
                if key == "ensemble":
                    val = _abs_source(str(val), scene_path.parent)
                ET.SubElement(new, "string", {"name": key, "value": str(val)})
        idx = list(parent).index(elem)
        parent.remove(elem)
        parent.insert(idx, new)
    return root


def _ids(root: ET.Element) -> set[str]:
    return {e.get("id") for e in root.iter() if e.get("id")}


def _find_by_id(root: ET.Element, mid: str):
    for parent in root.iter():
        for child in parent:
            if child.get("id") == mid:
                return parent, child
    return None, None


def _defaults(root: ET.Element, params: Mapping[str, object] | None) -> dict[str, str]:
    """The scene's ``<default>`` values with ``params`` on top."""
    out = {d.get("name"): d.get("value", "") for d in root.iter("default")}
    out.update({k: str(v) for k, v in (params or {}).items()})
    return out


def data_search_path(scene_path: str | os.PathLike) -> list[Path]:
    """Folders a scene's relative data files are looked up in, in order: the scene's own
    folder, then the shared environment maps (where the non-redistributable Grace Cathedral
    map of the paper's scene lives)."""
    folders = [Path(scene_path).resolve().parent]
    shared = shared_envmaps_dir()
    if shared is not None:
        folders.append(shared)
    return folders


def check_scene_data(scene_path: str | os.PathLike,
                     params: Mapping[str, object] | None = None) -> None:
    """Raise :class:`MissingDataError` (one line) when an emitter's image file of the scene
    is on none of :func:`data_search_path`'s folders (e.g. ``paper_sphere.xml`` without
    ``../shared/data/envmaps/grace_latlong.exr``)."""
    scene_path = Path(scene_path)
    root = parse_scene(scene_path).getroot()
    values = _defaults(root, params)
    for em in root.iter("emitter"):
        for el in em.iter("string"):
            if el.get("name") != "filename":
                continue
            name = el.get("value", "")
            if name.startswith("$"):
                name = values.get(name[1:], name)
            p = Path(name).expanduser()
            if p.is_absolute() and p.is_file():
                continue
            if any((f / p).is_file() for f in data_search_path(scene_path)):
                continue
            raise MissingDataError(
                f"{scene_path.name}: its environment map {name} is not on this machine "
                f"(looked in {', '.join(str(f) for f in data_search_path(scene_path))}); "
                "the paper's Grace Cathedral map is not redistributable: put the shared data "
                "folder at ../shared/data or point SPARSE_BRDF_DATA to it")


@contextlib.contextmanager
def _scene_dir_resolver(scene_path: Path) -> Iterator[None]:
    """Let Mitsuba resolve the scene's relative paths (envmaps/...) from
    :func:`data_search_path`."""
    import mitsuba as mi  # lazy: Mitsuba is slow to import (see the module doc)

    saved = mi.FileResolver(mi.file_resolver())
    for folder in reversed(data_search_path(scene_path)):
        mi.file_resolver().prepend(str(folder))
    try:
        yield
    finally:
        mi.set_file_resolver(saved)


#: The film of a scene without one: Mitsuba's ``hdrfilm`` default size (width, height).
DEFAULT_FILM = (768, 576)
#: The settings a render takes (:data:`RENDER_PARAMETERS`) and where Mitsuba keeps them in
#: a scene that does not declare them as ``<default>`` parameters.
_SAMPLER_KEYS = {"spp": "sample_count", "seed": "seed"}
#: The sampling of every comparison of renders: cosine BSDF sampling gives the same
#: sample paths whatever the material, so two renders of one seed and spp share their
#: Monte Carlo noise (the plugins' default, lobe sampling, adapts paths to each material).
SHARED_PATHS = "cosine"

Size = int | tuple[int, int]


def declared_parameters(scene_path: str | os.PathLike) -> dict[str, str]:
    """The ``$``-parameters a scene declares (its ``<default>`` elements): name -> value."""
    return _defaults(parse_scene(find_scene(scene_path)).getroot(), None)


def _sensor(root: ET.Element) -> ET.Element | None:
    """The scene's first sensor (the one Mitsuba renders), or None."""
    return next(root.iter("sensor"), None)


def _child(parent: ET.Element, tag: str, name: str) -> ET.Element | None:
    return next((e for e in parent if e.tag == tag and e.get("name") == name), None)


def _set_integer(parent: ET.Element, name: str, value: int) -> None:
    """Set (or add) ``<integer name=NAME>`` of ``parent``."""
    el = _child(parent, "integer", name)
    if el is None:
        el = ET.SubElement(parent, "integer", {"name": name})
    el.set("value", str(int(value)))


def _integer(parent: ET.Element | None, name: str, values: Mapping[str, str],
             default: int) -> int:
    """An ``<integer>`` of ``parent`` (a ``$`` reference resolved from ``values``)."""
    el = None if parent is None else _child(parent, "integer", name)
    if el is None:
        return default
    text = el.get("value", "")
    if text.startswith("$"):
        text = values.get(text[1:], text)
    try:
        return int(float(text))
    except ValueError:
        return default


def _film_size(root: ET.Element, values: Mapping[str, str]) -> tuple[int, int]:
    """(width, height) of the first sensor's film, ``$`` references resolved."""
    sensor = _sensor(root)
    film = None if sensor is None else sensor.find("film")
    return (_integer(film, "width", values, DEFAULT_FILM[0]),
            _integer(film, "height", values, DEFAULT_FILM[1]))


def film_size(scene_path: str | os.PathLike, res: Size | None = None,
              params: Mapping[str, object] | None = None) -> tuple[int, int]:
    """The (width, height) in pixels that :func:`render_scene` renders ``scene_path`` at
    for ``res`` (see there) and the scene defaults ``params``."""
    root = parse_scene(find_scene(scene_path)).getroot()
    values = _defaults(root, params)
    if res is None:
        return _film_size(root, values)
    if isinstance(res, tuple):
        return int(res[0]), int(res[1])
    if "res" in values:
        return _film_size(root, {**values, "res": str(int(res))})
    return _scaled(_film_size(root, values), int(res))


def _check_size(res: Size) -> Size:
    """``res`` checked: an int, or (width, height), each within RENDER_PARAMETERS['res']."""
    if isinstance(res, tuple):
        if len(res) != 2:
            raise UsageError(f"res: expected N or (width, height), got {res!r}")
        return tuple(int(check("res", int(v), RENDER_PARAMETERS["res"])) for v in res)
    return int(check("res", res, RENDER_PARAMETERS["res"]))


def _settings(root: ET.Element, scene_path: Path, spp, seed, res,
              params: Mapping[str, object] | None) -> dict[str, str]:
    """Apply spp, seed, res and ``params`` to a scene: the ``$``-parameters it declares
    are returned (for ``mi.load_string``), the rest is set on ``root`` itself (the first
    sensor's sampler and film). A ``params`` key the scene does not declare is refused."""
    declared = _defaults(root, None)
    given = {k: str(v) for k, v in (params or {}).items()}
    unknown = sorted(set(given) - set(declared))
    if unknown:
        raise UsageError(f"{scene_path}: {', '.join(unknown)} is not a parameter of the "
                         f"scene (it declares {', '.join(sorted(declared)) or 'none'})")
    kwargs = dict(given)
    sensor = _sensor(root)
    for key, val in (("spp", spp), ("seed", seed)):
        if val is None:
            continue
        val = check(key, val, RENDER_PARAMETERS[key])  # 0 spp is a SIGFPE inside Mitsuba
        if key in declared:
            kwargs[key] = str(val)
        elif sensor is not None:
            sampler = sensor.find("sampler")
            if sampler is None:
                sampler = ET.SubElement(sensor, "sampler", {"type": "independent"})
            _set_integer(sampler, _SAMPLER_KEYS[key], val)
    if res is not None:
        res = _check_size(res)
        square = not isinstance(res, tuple) or res[0] == res[1]
        if "res" in declared and square:
            kwargs["res"] = str(res if not isinstance(res, tuple) else res[0])
        elif sensor is not None:
            w, h = res if isinstance(res, tuple) else _scaled(
                _film_size(root, {**declared, **kwargs}), res)
            film = sensor.find("film")
            if film is None:
                film = ET.SubElement(sensor, "film", {"type": "hdrfilm"})
            for name in ("crop_offset_x", "crop_offset_y", "crop_width", "crop_height"):
                el = _child(film, "integer", name)
                if el is not None:
                    film.remove(el)
            _set_integer(film, "width", w)
            _set_integer(film, "height", h)
    return kwargs


def _scaled(size: tuple[int, int], res: int) -> tuple[int, int]:
    """``size`` scaled so that its longer side is ``res`` pixels."""
    scale = res / max(size)
    return max(1, round(size[0] * scale)), max(1, round(size[1] * scale))


def _with_sampling(options: Mapping[str, object] | None,
                   sampling: str | None) -> dict[str, object] | None:
    if sampling is None:
        return None if options is None else dict(options)
    return {**(options or {}), "sampling": check_choice("sampling", sampling, SAMPLING)}


def load_scene(
    scene_path: str | os.PathLike,
    materials: Mapping[str, str] | None = None,
    spp: int | None = None,
    seed: int | None = None,
    res: Size | None = None,
    variant: str = DEFAULT_VARIANT,
    params: Mapping[str, object] | None = None,
    sparse_options: Mapping[str, object] | None = None,
    tabulated_options: Mapping[str, object] | None = None,
    sampling: str | None = None,
    _edit=None,
):
    """Load a scene with material overrides (see :func:`render_scene`); returns mi.Scene.
    ``scene_path`` is a path, or the name of a shipped scene (:func:`find_scene`)."""
    import mitsuba as mi  # lazy: Mitsuba is slow to import (see the module doc)

    import mitsuba_plugin  # lazy: imports Mitsuba and Dr.Jit

    scene_path = require_file(find_scene(scene_path), "scene file")
    root = _replaced(scene_path, materials, _with_sampling(sparse_options, sampling),
                     _with_sampling(tabulated_options, sampling))
    kwargs = _settings(root, scene_path, spp, seed, res, params)
    if _edit is not None:
        _edit(root)
    check_scene_data(scene_path, kwargs)
    set_variant(variant)
    mitsuba_plugin.register()
    xml = ET.tostring(root, encoding="unicode")
    try:
        with _scene_dir_resolver(scene_path):
            return mi.load_string(xml, **kwargs)
    except Exception as exc:  # noqa: BLE001 - re-raised with the cause's message
        raise RenderError(f"{scene_path}: cannot load the scene: {_cause_message(exc)}") from exc


def render_scene(
    scene_path: str | os.PathLike,
    materials: Mapping[str, str] | None = None,
    spp: int = 64,
    seed: int = 0,
    res: Size | None = None,
    variant: str = DEFAULT_VARIANT,
    params: Mapping[str, object] | None = None,
    sparse_options: Mapping[str, object] | None = None,
    tabulated_options: Mapping[str, object] | None = None,
    sampling: str | None = None,
) -> np.ndarray:
    """Render ``scene_path`` (any Mitsuba 3 scene file) and return a linear float32 image
    of shape (H, W, 3).

    ``materials`` maps BSDF ids to BRDF sources: a ``.sbrdf`` file becomes
    ``sparse_brdf``, anything else ``tabulated_brdf`` (MERL ``.binary``, ``.h5``,
    ``mitsuba:<name>``). ``spp`` and ``seed`` fill the scene's ``$spp``/``$seed``
    parameters where it declares them, else they are set on its sampler. ``res``: None
    keeps the scene's film; an int N fills ``$res`` where the scene declares it, else
    scales the film so that its longer side is N pixels (its aspect ratio kept); a
    (width, height) pair sets the film's size. ``params`` sets other declared parameters
    (e.g. ``{"envmap": "envmaps/studio.exr"}``; one the scene does not declare is a
    :class:`~sparse_brdf.errors.UsageError`); ``sparse_options``/``tabulated_options``
    add plugin parameters (e.g. ``{"decoder": "strict"}``); ``sampling`` sets the
    replaced materials' BSDF sampling (None: the plugins' default, ``"lobe"``).
    With ``sampling="cosine"`` (:data:`SHARED_PATHS`) the same ``seed`` and ``spp`` give
    the same sample paths for every material, as comparisons of renders need.
    """
    import mitsuba as mi  # lazy: Mitsuba is slow to import (see the module doc)

    scene = load_scene(scene_path, materials, spp, seed, res, variant, params,
                       sparse_options, tabulated_options, sampling)
    try:
        img = mi.render(scene, spp=int(spp), seed=int(seed))
        out = np.array(img, dtype=np.float32)
    except Exception as exc:  # noqa: BLE001 - re-raised with the cause's message
        raise RenderError(f"{scene_path}: rendering failed: {_cause_message(exc)}") from exc
    if out.ndim != 3 or out.shape[2] < 3:
        raise RenderError(f"{scene_path}: expected an RGB image, got shape {out.shape}")
    out = np.ascontiguousarray(out[..., :3])
    bad = int(out.size - np.count_nonzero(np.isfinite(out)))
    if bad:  # e.g. a material whose values overflow float32 where the camera sees it
        names = ", ".join(f"{k}={v}" for k, v in (materials or {}).items()) or "none"
        raise RenderError(f"{scene_path}: the render holds {bad} NaN/inf pixel values: a "
                          f"material's values overflow (overridden materials: {names})")
    return out


#: Prefix of the ids given to shapes without one, to find them in the loaded scene.
_SHAPE_ID = "__object_"


def _carrying_shapes(root: ET.Element, materials: Iterable[str]) -> list[ET.Element]:
    """The ``<shape>`` elements that carry one of the BSDFs ``materials`` (ids): directly,
    by reference, or inside a BSDF that wraps it (``twosided``, ``blendbsdf``)."""
    carrying = set(materials)
    grown = True
    while grown:  # a wrapper with an id carries what it wraps
        grown = False
        for el in root.iter("bsdf"):
            eid = el.get("id")
            if eid and eid not in carrying and any(
                    d is not el and d.tag in ("bsdf", "ref") and d.get("id") in carrying
                    for d in el.iter()):
                carrying.add(eid)
                grown = True
    return [s for s in root.iter("shape")
            if any(d.tag in ("bsdf", "ref") and d.get("id") in carrying for d in s.iter())]


def object_mask(
    scene_path: str | os.PathLike,
    res: Size | None = None,
    params: Mapping[str, object] | None = None,
    subsamples: int = 4,
    variant: str = DEFAULT_VARIANT,
    materials: Iterable[str] | None = None,
) -> np.ndarray:
    """The object's pixels: bool (H, W).

    Traces ``subsamples`` x ``subsamples`` stratified camera rays through every pixel of the
    scene's first sensor (``res`` as in :func:`render_scene`); a pixel is an object pixel
    when any of them first hits a shape carrying one of the BSDFs ``materials`` (ids,
    e.g. the replaced ones; a ground plane or other geometry of other materials is not
    the object). ``materials=None`` counts every shape. The mask comes from the scene
    itself, never from image values; it selects the pixels of the *object-only* SNR.
    """
    import drjit as dr  # lazy: Dr.Jit and Mitsuba are slow to import (see the module doc)
    import mitsuba as mi

    n = int(subsamples)
    if n < 1:
        raise ValueError(f"object_mask: subsamples must be >= 1, got {n}")
    wanted = None if materials is None else list(materials)
    ids: set[str] = set()

    def tag(root: ET.Element) -> None:
        known = _ids(root)
        missing = sorted(set(wanted) - known)
        if missing:
            raise UnknownNameError(f"{scene_path}: no BSDF with id {', '.join(missing)} (ids: "
                                   f"{', '.join(sorted(known)) or 'none'})")
        for i, shape in enumerate(_carrying_shapes(root, wanted)):
            if not shape.get("id"):
                shape.set("id", f"{_SHAPE_ID}{i}")
            ids.add(shape.get("id"))

    scene = load_scene(scene_path, None, spp=1, res=res, variant=variant, params=params,
                       _edit=None if wanted is None else tag)
    sensor = scene.sensors()[0]
    width, height = (int(v) for v in sensor.film().crop_size())
    ys, xs, sy, sx = np.meshgrid(np.arange(height), np.arange(width), np.arange(n),
                                 np.arange(n), indexing="ij")
    u = ((xs + (sx + 0.5) / n) / width).ravel().astype(np.float32)
    v = ((ys + (sy + 0.5) / n) / height).ravel().astype(np.float32)
    ray, _ = sensor.sample_ray(mi.Float(0.0), mi.Float(0.5), mi.Point2f(u, v),
                               mi.Point2f(0.5, 0.5))
    pi = scene.ray_intersect_preliminary(ray)
    hit = pi.is_valid()
    if wanted is not None:
        on = dr.zeros(mi.Bool, dr.width(hit))
        for shape in scene.shapes():
            if shape.id() in ids:
                on |= pi.shape == mi.ShapePtr(shape)
        hit = hit & on
    dr.eval(hit)
    return np.asarray(hit, dtype=bool).reshape(height, width, n * n).any(-1)


def noise_floor(
    scene_path: str | os.PathLike,
    materials: Mapping[str, str] | None = None,
    spp: int = 64,
    seeds: tuple[int, int] = (0, 1),
    mask: np.ndarray | None = None,
    **kwargs,
) -> SNRForms:
    """SNR (dB, both forms) between two renders of the same (reference) materials with two
    seeds: the Monte Carlo noise level that a model-vs-reference comparison must be read
    against when seeds are not shared. ``mask``: the object pixels (see
    :func:`object_mask`); None computes it from the scene."""
    if seeds[0] == seeds[1]:
        raise ValueError("noise_floor needs two different seeds")
    kwargs.setdefault("sampling", SHARED_PATHS)
    a = render_scene(scene_path, materials, spp=spp, seed=seeds[0], **kwargs)
    b = render_scene(scene_path, materials, spp=spp, seed=seeds[1], **kwargs)
    if mask is None:
        mask = object_mask(scene_path, res=kwargs.get("res"), params=kwargs.get("params"),
                           materials=list(materials) if materials else None)
    return noise_floor_snr(a, b, mask)


def noise_floor_snr(reference: np.ndarray, reference2: np.ndarray,
                    mask: np.ndarray) -> SNRForms:
    """The noise floor from two renders of the same reference materials that differ only
    in their seed: the SNR (dB, both forms) of one against the other. ``mask``: the
    object pixels (see :func:`object_mask`)."""
    return snr_forms(reference, reference2, mask)


# ------------------------------------------------------------------------------- EXR


def write_exr(path: str | os.PathLike, img: np.ndarray) -> Path:
    """Write a linear float32 RGB image (H, W, 3) as an EXR file, atomically;
    :class:`OutputError` naming ``path`` if the system refuses (a full disk, a file size
    limit), with nothing left behind."""
    path = Path(path)
    arr = np.ascontiguousarray(np.asarray(img, dtype=np.float32))
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ImageFileError(f"{path}: expected an image of shape (H, W, 3), got "
                             f"{arr.shape}")
    import OpenEXR  # lazy: only image commands need it, every command imports this module

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path, suffix=".exr") as tmp, OpenEXR.File(header, {"RGB": arr}) as f:
        try:
            f.write(str(tmp))
        except RuntimeError as exc:  # OpenEXR's I/O errors (ENOSPC, EFBIG, ...)
            raise OutputError(f"{path}: cannot write the EXR image: {exc}") from exc
    return path


#: The images a render writes, by suffix: ``.exr`` linear HDR (float32), the others an
#: 8-bit tone-mapped sRGB preview (:func:`preview`).
IMAGE_SUFFIXES = (".exr", ".png", ".jpg", ".jpeg")
#: The object masks :func:`write_mask` writes, by suffix.
MASK_SUFFIXES = (".exr", ".npy")


def preview(img: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """An 8-bit sRGB preview of a linear image (H, W, 3): scaled by ``2 ** exposure``
    (stops), clipped to [0, 1] and encoded with the sRGB transfer function; uint8
    (H, W, 3). NaN and negative values show as black."""
    x = np.nan_to_num(np.asarray(img, np.float64) * 2.0 ** float(exposure), nan=0.0)
    x = np.clip(x, 0.0, 1.0)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(x * 255.0).astype(np.uint8)


def write_image(path: str | os.PathLike, img: np.ndarray, exposure: float = 0.0) -> Path:
    """Write a linear RGB image (H, W, 3) by its suffix, atomically: ``.exr`` as linear
    float32 (``exposure`` unused), ``.png``/``.jpg``/``.jpeg`` as an 8-bit sRGB preview
    (:func:`preview`, ``exposure`` in stops); another suffix is an
    :class:`~sparse_brdf.errors.OutputError`."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".exr":
        return write_exr(path, img)
    if suffix not in IMAGE_SUFFIXES:
        raise OutputError(f"{path}: an image is written as {', '.join(IMAGE_SUFFIXES)}")
    arr = np.asarray(img)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ImageFileError(f"{path}: expected an image of shape (H, W, 3), got "
                             f"{arr.shape}")
    from PIL import Image  # lazy: only previews need it (Pillow comes with matplotlib)

    fmt = "PNG" if suffix == ".png" else "JPEG"
    with atomic_write(path, "wb") as f:
        Image.fromarray(preview(arr, exposure), "RGB").save(f, format=fmt, quality=95)
    return path


def read_exr(path: str | os.PathLike) -> np.ndarray:
    """Read the RGB channels of an EXR file (RGB or RGBA, as Mitsuba writes) as float32
    (H, W, 3); :class:`ImageFileError` naming the file if it is not such an image."""
    import OpenEXR  # lazy: only image commands need it, every command imports this module

    path = require_file(path, "EXR file")
    printed: list[str] = []  # OpenEXR's own words about this file (see _c_output_to)
    try:
        with _c_output_to(printed, (str(path), "EXR_ERR", "pixel data")), \
                OpenEXR.File(str(path)) as f:
            ch = f.channels()
            key = next((k for k in ("RGB", "RGBA") if k in ch), None)
            if key is not None:
                arr = np.asarray(ch[key].pixels)[..., :3]
            elif all(c in ch for c in "RGB"):
                arr = np.stack([np.asarray(ch[c].pixels) for c in "RGB"], -1)
            else:
                raise ImageFileError(f"no R, G, B channels (has {', '.join(ch) or 'none'})")
    except Exception as exc:  # noqa: BLE001 - OpenEXR raises plain exceptions
        said = printed[0].strip().splitlines() if printed and printed[0].strip() else []
        raise ImageFileError(f"{path}: cannot read EXR: {exc}"
                             + (f" ({said[0].removeprefix(f'{path}: ')})" if said else "")
                             ) from exc
    if printed and printed[0].strip():  # OpenEXR warned of damaged pixel data
        line = printed[0].strip().splitlines()[0].removeprefix(f"{path}: ")
        raise ImageFileError(f"{path}: cannot read EXR: {line}")
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.size == 0:
        raise ImageFileError(f"{path}: not an RGB image (pixel array of shape {arr.shape})")
    return np.ascontiguousarray(arr, dtype=np.float32)


@contextlib.contextmanager
def _c_output_to(printed: list[str], marks: tuple[str, ...]) -> Iterator[None]:
    """Collect the lines that C/C++ libraries print on file descriptors 1 and 2 and that
    hold one of ``marks`` (OpenEXR's warnings about a damaged file, on both) into
    ``printed`` (one string) instead of the terminal; other lines (another thread's) go
    to stderr afterwards. An unnamed temporary file holds them, so an interrupt leaves
    nothing behind."""
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:  # no stdout or stderr: nothing to protect
        yield
        return
    with tempfile.TemporaryFile() as tmp:
        sys.stdout.flush()
        sys.stderr.flush()
        for fd in (1, 2):
            os.dup2(tmp.fileno(), fd)
        try:
            yield
        finally:
            for fd, old in zip((1, 2), saved, strict=True):
                os.dup2(old, fd)
                os.close(old)
            tmp.seek(0)
            lines = tmp.read().decode("utf-8", errors="replace").splitlines(keepends=True)
            ours = [ln for ln in lines if any(m in ln for m in marks)]
            others = "".join(ln for ln in lines if ln not in ours)
            if others:
                sys.stderr.write(others)
            printed.append("".join(ours))


def write_mask(path: str | os.PathLike, mask: np.ndarray) -> Path:
    """Write a bool mask (H, W) as an EXR (1.0 = object, in every channel) or, for a
    ``.npy`` path, as a numpy array; atomically."""
    path = Path(path)
    mask = np.asarray(mask, dtype=bool)
    if path.suffix.lower() == ".npy":
        with atomic_write(path, "wb") as f:
            np.save(f, mask)
        return path
    return write_exr(path, np.repeat(mask[..., None], 3, -1).astype(np.float32))


def read_mask(path: str | os.PathLike) -> np.ndarray:
    """An object mask, bool (H, W), from an EXR (nonzero in any channel = object) or a
    ``.npy`` file of booleans."""
    path = require_file(path, "mask file")
    if path.suffix.lower() == ".npy":
        try:
            mask = np.load(path, allow_pickle=False)
        except Exception as exc:  # noqa: BLE001 - numpy raises several kinds
            raise ImageFileError(f"{path}: cannot read mask: {exc}") from exc
        if mask.ndim != 2 or mask.dtype.kind not in "biuf":
            raise ImageFileError(f"{path}: a mask must be a 2-D (H, W) array of booleans, "
                                 f"got {mask.dtype} of shape {mask.shape}")
        return mask.astype(bool)
    img = read_exr(path)
    if not np.all(np.isfinite(img)):
        raise ImageFileError(f"{path}: mask holds NaN/inf values")
    return np.any(img != 0, axis=-1)
