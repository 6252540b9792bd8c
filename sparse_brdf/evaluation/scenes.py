"""Scenes and their materials: finding a scene by name, scene specs ``NAME:KEY=VALUE``,
reading a scene file, and the scene XML with overridden materials (``sparse_brdf`` for a
``.sbrdf`` file, ``tabulated_brdf`` for any other source; ``docs/method.md``, "Rendering
with Mitsuba"). Errors raised inside a render surface as "drjit.custom ... (see above)";
the real message is found on the ``__cause__`` chain here.

Mitsuba is imported inside the functions that need it, so that ``import sparse_brdf`` and
``sparse-brdf --help`` never load it.
"""

from __future__ import annotations

import contextlib
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import NamedTuple

from ..errors import (
    InputFileError,
    MissingDataError,
    MissingFileError,
    SceneError,
    SparseBRDFError,
    UnknownNameError,
    UsageError,
)
from ..params import SEED, Interval
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
    if p.is_dir():
        inside = sorted(q.name for q in p.glob("*.xml"))
        raise InputFileError(f"{name}: a folder, not a scene file (give the .xml file"
                             + (f"; it holds {', '.join(inside[:8])}"
                                f"{', ...' if len(inside) > 8 else ''})" if inside else ")"))
    if p.exists():
        raise InputFileError(f"{name}: not a regular file (a pipe or device), expected a "
                             "scene file")
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
    taken = scene_parameters(parse_scene(path).getroot())
    unknown = sorted(set(params) - taken)
    if unknown:
        raise UsageError(f"scene {text!r}: {path.name} declares no parameter "
                         f"{', '.join(unknown)} (it has {', '.join(sorted(taken))})")
    # the key names folders and files: a value's path separators become underscores
    key = path.stem + "".join(f"-{k}={_SEPARATORS.sub('_', v)}" for k, v in params.items())
    return SceneSpec(path, params, key)


def parse_overrides(items: Iterable[str], option: str = "--material") -> dict[str, str]:
    """``["id=FILE", ...]`` -> ``{"id": "FILE"}`` (a bare FILE means id "material").

    An id given twice is a :class:`~sparse_brdf.errors.UsageError` naming ``option``
    and the id (no override silently wins over another)."""
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            key, value = "material", item
        key, value = key.strip(), value.strip()
        if not key or not value:
            raise UsageError(f"{option} {item!r}: expected ID=FILE")
        if key in out:
            raise UsageError(f"{option} {key}: given twice ({out[key]} and {value}); give "
                             "each id one material")
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


def cause_message(exc: BaseException) -> str:
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


@contextlib.contextmanager
def files_found_in(folders: list[Path]) -> Iterator[None]:
    """Let Mitsuba look relative file names up in ``folders`` (in order, before its own
    search path) within the block."""
    import mitsuba as mi  # lazy: Mitsuba is slow to import (see the module doc)

    saved = mi.FileResolver(mi.file_resolver())
    for folder in reversed(folders):
        mi.file_resolver().prepend(str(folder))
    try:
        yield
    finally:
        mi.set_file_resolver(saved)


def parse_scene(scene_path: str | os.PathLike) -> ET.ElementTree:
    """A scene's XML tree, its ``<include>`` elements replaced by what they include.

    Mitsuba reads an ``<include filename="..."/>`` as the children of the included file's
    ``<scene>``, put where the include stands (its ids, ``<default>`` parameters and
    ``$`` references among the scene's own, in document order); a relative name is looked
    up in the including file's folder first, then in the scene's (so an included file
    includes others relative to itself). The included files' data files (meshes, maps)
    are looked up as the scene's own are, from the scene's folder, as Mitsuba does. The
    tree returned is therefore the scene Mitsuba loads, and written out
    (``mi.load_string``) it loads the same way.

    Raises
    ------
    SceneError
        The file or an included one is malformed, or includes itself (directly or not).
    MissingDataError
        An included file is not there (the message names the including file).
    """
    path = Path(scene_path)
    tree = _parse_xml(path)
    _inline_includes(tree.getroot(), path, path.parent, ())
    return tree


def _parse_xml(path: Path) -> ET.ElementTree:
    try:
        return ET.parse(path)
    except ET.ParseError as exc:
        raise SceneError(f"{path}: not a valid scene XML file: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise SceneError(f"{path}: not a valid scene XML file ({exc.reason})") from exc


#: How deep includes may nest (Mitsuba's parser refuses deeper nesting as well).
_MAX_INCLUDE_DEPTH = 32


def _inline_includes(elem: ET.Element, path: Path, scene_dir: Path,
                     chain: tuple[Path, ...]) -> None:
    """Replace, under ``elem`` (of file ``path``), every ``<include>`` by the children of
    the included file's root, recursively (see :func:`parse_scene`)."""
    chain = (*chain, path.resolve())
    for i, child in reversed(list(enumerate(elem))):
        if child.tag != "include":
            _inline_includes(child, path, scene_dir, chain[:-1])
            continue
        name = child.get("filename", "")
        if not name:
            raise SceneError(f"{path}: an <include> without a filename")
        target = _included_file(path, name, scene_dir)
        if target.resolve() in chain or len(chain) >= _MAX_INCLUDE_DEPTH:
            raise SceneError(f"{path}: <include filename={name!r}> includes "
                             f"{target.name} again (a cycle of includes)")
        root = _parse_xml(target).getroot()
        _inline_includes(root, target, scene_dir, chain)
        elem.remove(child)
        for j, inner in enumerate(list(root) if root.tag == "scene" else [root]):
            elem.insert(i + j, inner)


def _included_file(path: Path, name: str, scene_dir: Path) -> Path:
    """The file ``<include filename=name>`` of file ``path`` names: in ``path``'s
    folder, then the scene's, then the current folder."""
    p = Path(name).expanduser()
    folders = [] if p.is_absolute() else list(dict.fromkeys(
        [path.parent, scene_dir, Path.cwd()]))
    for cand in [p] if p.is_absolute() else [f / p for f in folders]:
        if cand.is_file():
            return cand
    looked = str(p) if p.is_absolute() else ", ".join(str(f) for f in folders)
    raise MissingDataError(f"{path}: includes {name}, which is not there (looked in "
                           f"{looked})")


def _abs_source(value: str | os.PathLike) -> str:
    """A material or ensemble path as the scene holds it: absolute, taken from the current
    folder (a ``mitsuba:`` name as is). The one resolution of the path: the plugins take
    an absolute name as given."""
    value = os.fspath(value)
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

    A replaced ``twosided`` BSDF stays two-sided: the material goes inside a new
    ``twosided`` wrapper that keeps the id (the plugins shade the front side only, so a
    bare plugin would render the back faces black); its two sides get the one material.

    ``sparse_options``/``tabulated_options`` are extra plugin parameters (e.g.
    ``{"decoder": "strict", "ensemble": path}``), written as strings (booleans as
    ``<boolean>``). Relative material paths are taken from the current directory.
    """
    root = replaced_materials(scene_path, materials, sparse_options, tabulated_options)
    return ET.tostring(root, encoding="unicode")


def replaced_materials(scene_path, materials, sparse_options, tabulated_options) -> ET.Element:
    """The scene's XML root with the BSDFs of ``materials`` replaced (:func:`scene_xml`)."""
    scene_path = Path(scene_path)
    root = parse_scene(scene_path).getroot()
    check_bsdf_ids(scene_path, materials or {}, root=root)
    for mid, source in (materials or {}).items():
        parent, elem = _find_by_id(root, mid)
        plugin = plugin_for(source)
        if elem.get("type") == "twosided":  # the plugins shade the front side only:
            outer = ET.Element("bsdf", {"type": "twosided", "id": mid})  # keep the wrapper
            new = ET.SubElement(outer, "bsdf", {"type": plugin})
        else:
            outer = new = ET.Element("bsdf", {"type": plugin, "id": mid})
        ET.SubElement(new, "string", {"name": "filename",
                                      "value": _abs_source(source)})
        opts = sparse_options if plugin == "sparse_brdf" else tabulated_options
        for key, val in (opts or {}).items():
            if isinstance(val, bool):
                ET.SubElement(new, "boolean", {"name": key, "value": str(val).lower()})
            else:
                if key == "ensemble":
                    val = _abs_source(str(val))
                ET.SubElement(new, "string", {"name": key, "value": str(val)})
        idx = list(parent).index(elem)
        parent.remove(elem)
        parent.insert(idx, outer)
    return root


def element_ids(root: ET.Element) -> set[str]:
    """Every id the scene's elements carry (BSDFs, shapes, emitters, textures...)."""
    return {e.get("id") for e in root.iter() if e.get("id")}


def bsdf_ids(root: ET.Element) -> list[str]:
    """The ids of the scene's BSDFs, sorted."""
    return sorted({e.get("id") for e in root.iter("bsdf") if e.get("id")})


def _find_by_id(root: ET.Element, mid: str):
    """(parent, element) of the element that defines id ``mid`` (not a ``<ref>`` to it),
    or (None, None)."""
    for parent in root.iter():
        for child in parent:
            if child.get("id") == mid and child.tag != "ref":
                return parent, child
    return None, None


def check_bsdf_ids(scene_path: str | os.PathLike, ids: Iterable[str],
                   option: str | None = None, root: ET.Element | None = None) -> None:
    """Refuse, in one line, an id of ``ids`` that names no BSDF of the scene.

    Parameters
    ----------
    scene_path : str or path-like
        The scene file.
    ids : iterable of str
        The BSDF ids to replace (or whose shapes are the object).
    option : str, optional
        The command-line option that gave them (``"--material"``), named in the message;
        None names the scene file instead.
    root : xml.etree.ElementTree.Element, optional
        The scene's parsed root (read from ``scene_path`` when None).

    Raises
    ------
    UnknownNameError
        An id no element of the scene carries.
    UsageError
        An id of an element that is not a BSDF (a shape, an emitter, a sensor, a
        texture...): replacing it would remove that element from the scene.
    """
    scene_path = Path(scene_path)
    if root is None:
        root = parse_scene(scene_path).getroot()
    listing = f"the BSDF ids of {scene_path.name}: {', '.join(bsdf_ids(root)) or 'none'}"
    for mid in ids:
        where = f"{option} {mid}" if option else f"{scene_path}: material id {mid!r}"
        _, elem = _find_by_id(root, mid)
        if elem is None:
            raise UnknownNameError(f"{where}: no element of the scene has that id ({listing})")
        if elem.tag != "bsdf":
            article = "an" if elem.tag[:1] in "aeiou" else "a"
            raise UsageError(f"{where}: that id is {article} {elem.tag}, not a BSDF ({listing})")


#: A ``$name`` reference in an attribute value, which Mitsuba fills from its parameters.
_REFERENCE = re.compile(r"\$([A-Za-z_]\w*)")


def scene_parameters(root: ET.Element) -> set[str]:
    """The parameters a scene takes: the names it refers to as ``$name`` in its
    attributes (Mitsuba refuses a value for any other, "Found unused parameters", even
    one the scene declares a ``<default>`` for)."""
    return {m for e in root.iter() if e.tag != "default" for v in e.attrib.values()
            for m in _REFERENCE.findall(v)}


def check_parameters(scene_path: str | os.PathLike, params: Iterable[str],
                     option: str | None = None, root: ET.Element | None = None) -> None:
    """Refuse, in one line, a parameter of ``params`` (names) that the scene does not take.

    Parameters
    ----------
    scene_path : str or path-like
        The scene file.
    params : iterable of str
        The names of the parameters to set (e.g. ``-D width=200``'s ``width``).
    option : str, optional
        What gave them (``"-D"``), named in the message; None names the scene file.
    root : xml.etree.ElementTree.Element, optional
        The scene's parsed root (read from ``scene_path`` when None).

    Raises
    ------
    UsageError
        A name the scene does not refer to as ``$name`` (see :func:`scene_parameters`);
        the message lists the ones it does.
    """
    scene_path = Path(scene_path)
    if root is None:
        root = parse_scene(scene_path).getroot()
    taken = scene_parameters(root)
    unknown = [k for k in dict.fromkeys(params) if k not in taken]
    if unknown:
        names = ", ".join(unknown)
        what = (f"{option} {names}: not a parameter of {scene_path.name}" if option else
                f"{scene_path}: {names} is not a parameter of the scene")
        raise UsageError(f"{what} (it uses no {', '.join('$' + k for k in unknown)}; its "
                         f"parameters: {', '.join(sorted(taken)) or 'none'})")


def declared_defaults(root: ET.Element, params: Mapping[str, object] | None) -> dict[str, str]:
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


#: The paper's environment map, which is not redistributable (``paper_sphere.xml``).
GRACE_MAP = "grace_latlong.exr"


def check_scene_data(scene_path: str | os.PathLike,
                     params: Mapping[str, object] | None = None,
                     replaced: Iterable[str] = ()) -> None:
    """Raise :class:`MissingDataError` (one line naming the file and the scene) when a
    data file the scene refers to (``<string name="filename">``: an environment map, a
    mesh, a texture's image) is on none of :func:`data_search_path`'s folders nor in the
    current folder, or is not a regular file.

    Parameters
    ----------
    scene_path : str or path-like
        The scene file.
    params : mapping, optional
        Parameter values set on top of its ``<default>`` ones (``$name`` in a file name is
        filled from them).
    replaced : iterable of str
        Ids of BSDFs that are replaced: their own files are not looked for.

    Raises
    ------
    MissingDataError
        For the first file missing. Only for the paper's Grace Cathedral map
        (:data:`GRACE_MAP`) does the message say where the shared data folder goes.
    """
    scene_path = Path(scene_path)
    root = parse_scene(scene_path).getroot()
    values = declared_defaults(root, params)
    replaced = set(replaced)
    skipped = {id(d) for e in root.iter("bsdf") if e.get("id") in replaced for d in e.iter()}
    folders = [*data_search_path(scene_path), Path.cwd()]
    for el in root.iter("string"):
        if el.get("name") != "filename" or id(el) in skipped:
            continue
        name = _REFERENCE.sub(lambda m: values.get(m.group(1), m.group()), el.get("value", ""))
        p = Path(name).expanduser()
        if p.is_file() if p.is_absolute() else any((f / p).is_file() for f in folders):
            continue
        looked = str(p) if p.is_absolute() else ", ".join(str(f) for f in folders)
        if p.name == GRACE_MAP:
            raise MissingDataError(
                f"{scene_path}: its environment map {name} is not on this machine (looked "
                f"in {looked}); the paper's Grace Cathedral map is not redistributable: put "
                "the shared data folder at ../shared/data or point SPARSE_BRDF_DATA to it")
        raise MissingDataError(f"{scene_path}: refers to {name}, which is not there (looked "
                               f"in {looked}); copy it beside the scene or fix the path")


def scene_dir_resolver(scene_path: Path) -> contextlib.AbstractContextManager:
    """Let Mitsuba resolve the scene's relative paths (envmaps/...) from
    :func:`data_search_path`."""
    return files_found_in(data_search_path(scene_path))
