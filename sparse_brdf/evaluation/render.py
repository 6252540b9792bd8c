"""Rendering: scenes with overridden materials rendered with Mitsuba 3, object masks, the
noise floor.

Any Mitsuba 3 scene file names its materials by id; :func:`render_scene` replaces each
overridden id by ``sparse_brdf`` (for a ``.sbrdf`` file) or ``tabulated_brdf`` (any other
source :func:`sparse_brdf.sources.load.load_brdf` reads; the scene XML is built in
:mod:`sparse_brdf.evaluation.scenes`) and renders with Mitsuba 3. The
scene's ``$``-parameters get values only where it declares them (``<default>``, as the
shipped ``scenes/`` declare ``spp``, ``res`` and ``seed``); otherwise spp and seed are set
on its first sensor's sampler and the resolution on its film (aspect ratio kept).
:func:`object_mask` gives the pixels of the object-only SNR: those whose camera rays first
hit a shape carrying one of the replaced materials. Images are written by suffix
(:mod:`sparse_brdf.evaluation.images`: ``.exr`` linear, ``.png``/``.jpg`` an sRGB
preview). Errors raised inside a render surface as "drjit.custom ... (see above)";
:class:`RenderError` carries the real message from the ``__cause__`` chain
(``docs/method.md``, "Rendering with Mitsuba").

Mitsuba, Dr.Jit and :mod:`mitsuba_plugin` are imported inside the functions that render,
so that ``import sparse_brdf`` and ``sparse-brdf --help`` never load them.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from ..decoders.layouts import LOBES
from ..errors import RenderError, UsageError
from ..fileio import require_file
from ..metrics import SNRForms, snr_forms
from ..mitsuba_env import DEFAULT_VARIANT, set_variant
from ..params import check, check_choice
from .libraries import to_libraries
from .scenes import (
    RENDER_PARAMETERS,
    cause_message,
    check_bsdf_ids,
    check_parameters,
    check_scene_data,
    declared_defaults,
    find_scene,
    parse_scene,
    replaced_materials,
    scene_dir_resolver,
    scene_parameters,
)

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
    return declared_defaults(parse_scene(find_scene(scene_path)).getroot(), None)


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
    values = declared_defaults(root, params)
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
    """Apply spp, seed, res and ``params`` to a scene: the ``$``-parameters it uses
    are returned (for ``mi.load_string``), the rest is set on ``root`` itself (the first
    sensor's sampler and film). A ``params`` key the scene does not use is refused, and
    so is a ``$``-parameter it uses without a ``<default>`` that nothing sets."""
    declared = declared_defaults(root, None)
    given = {k: str(v) for k, v in (params or {}).items()}
    check_parameters(scene_path, given, root=root)
    taken = scene_parameters(root)
    kwargs = dict(given)
    sensor = _sensor(root)
    for key, val in (("spp", spp), ("seed", seed)):
        if val is None:
            continue
        val = check(key, val, RENDER_PARAMETERS[key])  # 0 spp is a SIGFPE inside Mitsuba
        if key in taken:
            kwargs[key] = str(val)
        elif sensor is not None:
            sampler = sensor.find("sampler")
            if sampler is None:
                sampler = ET.SubElement(sensor, "sampler", {"type": "independent"})
            _set_integer(sampler, _SAMPLER_KEYS[key], val)
    if res is not None:
        res = _check_size(res)
        square = not isinstance(res, tuple) or res[0] == res[1]
        if "res" in taken and square:
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
    unset = sorted(taken - set(declared) - set(kwargs))
    if unset:
        raise UsageError(f"{scene_path}: the scene uses {', '.join('$' + k for k in unset)} "
                         f"but declares no <default> for {'them' if len(unset) > 1 else 'it'}"
                         f": give {', '.join(k + '=VALUE' for k in unset)} (-D on the command "
                         "line)")
    return kwargs


def _scaled(size: tuple[int, int], res: int) -> tuple[int, int]:
    """``size`` scaled so that its longer side is ``res`` pixels."""
    scale = res / max(size)
    return max(1, round(size[0] * scale)), max(1, round(size[1] * scale))


def _with_sampling(options: Mapping[str, object] | None,
                   sampling: str | None) -> dict[str, object] | None:
    if sampling is None:
        return None if options is None else dict(options)
    return {**(options or {}), "sampling": check_choice("sampling", sampling, LOBES)}


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
    memory_budget: float | None = None,
    libraries: bool = True,
):
    """Load a scene with material overrides (see :func:`render_scene`); returns mi.Scene.
    ``scene_path`` is a path, or the name of a shipped scene (:func:`find_scene`)."""
    import mitsuba as mi  # lazy: Mitsuba is slow to import (see the module doc)

    import mitsuba_plugin  # lazy: imports Mitsuba and Dr.Jit

    scene_path = require_file(find_scene(scene_path), "scene file")
    root = replaced_materials(scene_path, materials, _with_sampling(sparse_options, sampling),
                     _with_sampling(tabulated_options, sampling))
    kwargs = _settings(root, scene_path, spp, seed, res, params)
    if _edit is not None:
        _edit(root)
    # many sparse_brdf materials: one sparse_library (libraries.py), said in Mitsuba's log
    from mitsuba_plugin.loading import library_key  # lazy, as mitsuba_plugin above

    lines = (to_libraries(root, scene_path.parent, library_key,
                          memory_budget=memory_budget) if libraries and _edit is None else [])
    check_scene_data(scene_path, kwargs, replaced=materials or ())
    set_variant(variant)
    mitsuba_plugin.register()
    for line in lines:
        mi.Log(mi.LogLevel.Info, line)
    xml = ET.tostring(root, encoding="unicode")
    try:
        budget = None if memory_budget is None else int(float(memory_budget) * 2**20)
        with scene_dir_resolver(scene_path), mitsuba_plugin.memory_budget(budget):
            # a library's meshes must stay apart: Mitsuba merges the meshes that share a
            # BSDF (optimize=True), and their attributes with them
            scene = mi.load_string(xml, **kwargs, **({"optimize": False} if lines else {}))
        mitsuba_plugin.resolve()  # the auto materials' decoders, under the scene's budget
        if lines:
            mitsuba_plugin.check_scene(scene)
        return scene
    except Exception as exc:  # noqa: BLE001 - re-raised with the cause's message
        raise RenderError(f"{scene_path}: cannot load the scene: {cause_message(exc)}") from exc


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
    memory_budget: float | None = None,
    libraries: bool = True,
) -> np.ndarray:
    """Render ``scene_path`` (any Mitsuba 3 scene file) in Mitsuba's ``variant`` (one of
    :data:`~sparse_brdf.mitsuba_env.VARIANTS`) and return a linear float32 image of shape
    (H, W, 3): RGB, a spectral variant's converted by Mitsuba's film; (H, W, 1) in the
    mono ones.

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
    ``memory_budget`` (MiB, None: the plugin's default, 64) is the scene's budget of
    per-material decoder data: its ``sparse_brdf`` materials whose decoder is ``auto``
    get the fast (grouped) tables, largest speed gain per byte first, while they fit,
    and the compact (strict) decoder otherwise (docs/rendering.md, "Scenes with many
    materials"). ``libraries``: a scene's many ``sparse_brdf`` materials (at least
    :data:`~sparse_brdf.evaluation.libraries.LIBRARY_MIN_MATERIALS` on the automatic
    decoder, used by shapes directly) are served by one ``sparse_library``, said in
    Mitsuba's log (:func:`~sparse_brdf.evaluation.libraries.to_libraries`).
    """
    import mitsuba as mi  # lazy: Mitsuba is slow to import (see the module doc)

    scene = load_scene(scene_path, materials, spp, seed, res, variant, params,
                       sparse_options, tabulated_options, sampling,
                       memory_budget=memory_budget, libraries=libraries)
    try:
        img = mi.render(scene, spp=int(spp), seed=int(seed))
        out = np.array(img, dtype=np.float32)
    except Exception as exc:  # noqa: BLE001 - re-raised with the cause's message
        raise RenderError(f"{scene_path}: rendering failed: {cause_message(exc)}") from exc
    if out.ndim != 3 or out.shape[2] < 3 and out.shape[2] != 1:  # mono variants: 1
        raise RenderError(f"{scene_path}: expected an image, got shape {out.shape}")
    out = np.ascontiguousarray(out[..., :3])
    bad = int(out.size - np.count_nonzero(np.isfinite(out)))
    if bad:  # e.g. a material whose values overflow float32 where the camera sees it
        names = ", ".join(f"{k}={v}" for k, v in (materials or {}).items()) or "none"
        raise RenderError(f"{scene_path}: the render holds {bad} NaN/inf pixel values: a "
                          f"material's values overflow (overridden materials: {names})")
    return out


#: Prefix of the ids given to shapes' own BSDFs without one, to find them when loaded.
_BSDF_ID = "__object_bsdf_"


def _carried_bsdfs(root: ET.Element, materials: Iterable[str]) -> set[str]:
    """The ids of the BSDFs that shapes shade with (a shape's own ``<bsdf>`` or
    ``<ref>``) which are, or wrap (``twosided``, ``blendbsdf``), one of the BSDFs
    ``materials`` (ids); a shape's own BSDF without an id is given one. Mitsuba keeps a
    BSDF's id when it merges the meshes that share it (dropping theirs)."""
    carrying, size = set(materials), -1
    while size != len(carrying):  # a wrapper with an id carries what it wraps
        size = len(carrying)
        carrying |= {el.get("id") for el in root.iter("bsdf") if el.get("id") and any(
            d is not el and d.tag in ("bsdf", "ref") and d.get("id") in carrying
            for d in el.iter())}
    out = set()
    for i, shape in enumerate(root.iter("shape")):
        own = next((c for c in shape if c.tag == "bsdf" or c.tag == "ref"
                    and c.get("id") in carrying), None)
        if own is not None and any(d.tag in ("bsdf", "ref") and d.get("id") in carrying
                                   for d in own.iter()):
            own.set("id", own.get("id") or f"{_BSDF_ID}{i}")
            out.add(own.get("id"))
    return out


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
        check_bsdf_ids(scene_path, wanted, root=root)
        ids.update(_carried_bsdfs(root, wanted))

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
        for shape in scene.shapes():  # by its BSDF: merged meshes have no ids
            if shape.bsdf() is not None and shape.bsdf().id() in ids:
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

