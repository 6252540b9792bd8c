"""Rendering helpers: scenes with overridable materials, EXR files, the noise floor.

A scene (e.g. ``scenes/sphere.xml``) names its materials by id; :func:`render_scene`
replaces each overridden id by ``sparse_brdf`` (for a ``.sbrdf`` file) or
``tabulated_brdf`` (any other source :func:`sparse_brdf.io.load_brdf` reads), fills the
scene's ``<default>`` parameters (``spp``, ``res``, ``seed``, ...) and renders with
Mitsuba 3. Errors raised inside a render surface as "drjit.custom ... (see above)";
:class:`RenderError` carries the real message from the ``__cause__`` chain (SPEC 9).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

import numpy as np

from .errors import SparseBRDFError
from .metrics import render_snr
from .mitsuba_env import DEFAULT_VARIANT, set_variant

SPARSE_SUFFIX = ".sbrdf"


class RenderError(SparseBRDFError, RuntimeError):
    """A scene failed to load or render; the message holds the underlying cause."""


def parse_overrides(items: Iterable[str]) -> dict[str, str]:
    """``["id=FILE", ...]`` -> ``{"id": "FILE"}`` (a bare FILE means id "material")."""
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            key, value = "material", item
        key, value = key.strip(), value.strip()
        if not key or not value:
            raise ValueError(f"material override {item!r}: expected ID=FILE")
        out[key] = value
    return out


def plugin_for(source: str) -> str:
    """The plugin that renders ``source``: sparse_brdf for .sbrdf, else tabulated_brdf."""
    return "sparse_brdf" if str(source).lower().endswith(SPARSE_SUFFIX) else "tabulated_brdf"


def _cause_message(exc: BaseException) -> str:
    """The messages of ``exc`` and its causes, innermost last, without repetitions."""
    parts: list[str] = []
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        msg = str(e).strip()
        if msg and msg not in parts:
            parts.append(msg)
        e = e.__cause__ or e.__context__
    return " <- ".join(reversed(parts)) if len(parts) > 1 else (parts[0] if parts else
                                                                type(exc).__name__)


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
    scene_path = Path(scene_path)
    tree = ET.parse(scene_path)
    root = tree.getroot()
    for mid, source in (materials or {}).items():
        parent, elem = _find_by_id(root, mid)
        if elem is None:
            raise KeyError(f"{scene_path}: no element with id {mid!r} to override "
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
    return ET.tostring(root, encoding="unicode")


def _ids(root: ET.Element) -> set[str]:
    return {e.get("id") for e in root.iter() if e.get("id")}


def _find_by_id(root: ET.Element, mid: str):
    for parent in root.iter():
        for child in parent:
            if child.get("id") == mid:
                return parent, child
    return None, None


@contextlib.contextmanager
def _scene_dir_resolver(folder: Path) -> Iterator[None]:
    """Let Mitsuba resolve the scene's relative paths (envmaps/...) from ``folder``."""
    import mitsuba as mi

    saved = mi.FileResolver(mi.file_resolver())
    mi.file_resolver().prepend(str(folder.resolve()))
    try:
        yield
    finally:
        mi.set_file_resolver(saved)


def load_scene(
    scene_path: str | os.PathLike,
    materials: Mapping[str, str] | None = None,
    spp: int | None = None,
    seed: int | None = None,
    res: int | None = None,
    variant: str = DEFAULT_VARIANT,
    params: Mapping[str, object] | None = None,
    sparse_options: Mapping[str, object] | None = None,
    tabulated_options: Mapping[str, object] | None = None,
):
    """Load a scene with material overrides (see :func:`render_scene`); returns mi.Scene."""
    import mitsuba as mi

    import mitsuba_plugin

    scene_path = Path(scene_path)
    if not scene_path.is_file():
        raise FileNotFoundError(f"{scene_path}: no such scene file")
    set_variant(variant)
    mitsuba_plugin.register()
    xml = scene_xml(scene_path, materials, sparse_options, tabulated_options)
    kwargs = {k: str(v) for k, v in (params or {}).items()}
    for key, val in (("spp", spp), ("seed", seed), ("res", res)):
        if val is not None:
            kwargs[key] = str(int(val))
    try:
        with _scene_dir_resolver(scene_path.parent):
            return mi.load_string(xml, **kwargs)
    except Exception as exc:  # noqa: BLE001 - re-raised with the cause's message
        raise RenderError(f"{scene_path}: cannot load the scene: {_cause_message(exc)}") from exc


def render_scene(
    scene_path: str | os.PathLike,
    materials: Mapping[str, str] | None = None,
    spp: int = 64,
    seed: int = 0,
    res: int | None = None,
    variant: str = DEFAULT_VARIANT,
    params: Mapping[str, object] | None = None,
    sparse_options: Mapping[str, object] | None = None,
    tabulated_options: Mapping[str, object] | None = None,
) -> np.ndarray:
    """Render ``scene_path`` and return a linear float32 image of shape (H, W, 3).

    ``materials`` maps BSDF ids to BRDF sources: a ``.sbrdf`` file becomes
    ``sparse_brdf``, anything else ``tabulated_brdf`` (MERL ``.binary``, ``.h5``,
    ``mitsuba:<name>``). ``spp``, ``seed`` and ``res`` fill the scene's defaults of
    those names (``res=None`` keeps the scene's); ``params`` sets other defaults
    (e.g. ``{"envmap": "envmaps/studio.exr"}``); ``sparse_options``/
    ``tabulated_options`` add plugin parameters (e.g. ``{"decoder": "strict"}``).
    The same ``seed`` and ``spp`` give the same sample paths for every material under
    cosine BSDF sampling.
    """
    import mitsuba as mi

    scene = load_scene(scene_path, materials, spp, seed, res, variant, params,
                       sparse_options, tabulated_options)
    try:
        img = mi.render(scene, spp=int(spp), seed=int(seed))
        out = np.array(img, dtype=np.float32)
    except Exception as exc:  # noqa: BLE001 - re-raised with the cause's message
        raise RenderError(f"{scene_path}: rendering failed: {_cause_message(exc)}") from exc
    if out.ndim != 3 or out.shape[2] < 3:
        raise RenderError(f"{scene_path}: expected an RGB image, got shape {out.shape}")
    return np.ascontiguousarray(out[..., :3])


def noise_floor(
    scene_path: str | os.PathLike,
    materials: Mapping[str, str] | None = None,
    spp: int = 64,
    seeds: tuple[int, int] = (0, 1),
    **kwargs,
) -> float:
    """SNR (dB) between two renders of the same (reference) materials with two seeds.

    The Monte Carlo noise level a model-vs-reference comparison must be read against
    when seeds are not shared (SPEC section 8).
    """
    if seeds[0] == seeds[1]:
        raise ValueError("noise_floor needs two different seeds")
    a = render_scene(scene_path, materials, spp=spp, seed=seeds[0], **kwargs)
    b = render_scene(scene_path, materials, spp=spp, seed=seeds[1], **kwargs)
    return render_snr(a, b)


# ------------------------------------------------------------------------------- EXR


def write_exr(path: str | os.PathLike, img: np.ndarray) -> Path:
    """Write a linear float32 RGB image (H, W, 3) as an EXR file, atomically."""
    import OpenEXR

    path = Path(path)
    arr = np.ascontiguousarray(np.asarray(img, dtype=np.float32))
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"{path}: expected an image of shape (H, W, 3), got {arr.shape}")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".exr", dir=path.parent)
    os.close(fd)
    try:
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        with OpenEXR.File(header, {"RGB": arr}) as f:
            f.write(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    return path


def read_exr(path: str | os.PathLike) -> np.ndarray:
    """Read an RGB EXR file as float32 (H, W, 3)."""
    import OpenEXR

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such EXR file")
    try:
        with OpenEXR.File(str(path)) as f:
            ch = f.channels()
            if "RGB" in ch:
                arr = np.asarray(ch["RGB"].pixels)
            elif all(c in ch for c in "RGB"):
                arr = np.stack([np.asarray(ch[c].pixels) for c in "RGB"], -1)
            else:
                raise ValueError(f"no RGB channels (has {', '.join(ch)})")
    except Exception as exc:  # noqa: BLE001 - OpenEXR raises plain exceptions
        raise ValueError(f"{path}: cannot read EXR: {exc}") from exc
    return np.ascontiguousarray(arr, dtype=np.float32)
