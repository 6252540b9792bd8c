"""A scene's many ``sparse_brdf`` materials written as one ``sparse_library``.

Mitsuba traces every BSDF instance of a scene on every render, about a millisecond and
150 kB for each ``sparse_brdf`` (docs/records/many-materials-trace-2026-12-07.md). A
``sparse_library`` serves many materials from one instance, each shape naming its
material by an attribute. :func:`to_libraries` rewrites a scene's XML so: the
``sparse_brdf`` materials that shapes use directly (their own ``<bsdf>`` or a ``<ref>``
to one that nothing else refers to), on the automatic decoder, become one library per
set of options, ensemble and grid, when a set holds at least
:data:`LIBRARY_MIN_MATERIALS` materials; each of their shapes refers to the library and
holds ``sbrdf_index``. Other materials (inside wrappers, on a decoder asked for by name)
stay as they are.
:func:`~sparse_brdf.evaluation.render.load_scene` applies it.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

#: The fewest materials that :func:`to_libraries` serves from one library: below, each
#: ``sparse_brdf`` keeps its own BSDF, as the scene was written. Measured
#: (``benchmarks/many_materials.py``, 2026-12-07): on its pair decoder alone the library
#: rendered slower than separate BSDFs at 32 materials and faster at 100; under the
#: render's 64 MiB budget it was as fast from 24 on and took 0.62x their time at 64.
LIBRARY_MIN_MATERIALS = 64

#: The properties a ``sparse_brdf`` may set to join a library (their values must agree
#: within one); ``decoder`` only as "auto", ``layout`` and ``memory_budget`` only
#: choose among the decoders that the library replaces.
_JOINING = ("filename", "ensemble", "sampling", "interpolate", "decoder", "layout",
            "memory_budget")

#: Prefix of the ids given to the libraries written.
LIBRARY_ID = "__sparse_library_"


def _props(elem: ET.Element) -> dict | None:
    """The properties of a ``sparse_brdf`` element as {name: value}, or None if it
    cannot join a library (another property, a nested element, a decoder named)."""
    out = {}
    for child in elem:
        name, value = child.get("name"), child.get("value")
        if name not in _JOINING or value is None or value.startswith("$") or len(child):
            return None
        out[name] = value
    if "filename" not in out or out.get("decoder", "auto") != "auto":
        return None
    try:  # a budget that is no number: left to the material's own plugin to report
        float(out.get("memory_budget", 0.0))
    except ValueError:
        return None
    return out


def _candidates(root: ET.Element) -> list[tuple[ET.Element, ET.Element, dict]]:
    """(shape, its BSDF's element in it: a ``<bsdf>`` or ``<ref>``, the material's
    properties) for every shape that uses a ``sparse_brdf`` that may join a library."""
    refs: dict[str, int] = {}
    for el in root.iter("ref"):
        refs[el.get("id")] = refs.get(el.get("id"), 0) + 1
    top = {el.get("id"): el for el in root if el.tag == "bsdf" and el.get("id")}
    out, direct = [], {}
    for shape in root.iter("shape"):
        for child in shape:
            if child.tag == "bsdf" and child.get("type") == "sparse_brdf":
                props = _props(child)
                if props is not None:
                    out.append((shape, child, props))
            elif child.tag == "ref" and child.get("name") in (None, "bsdf"):
                el = top.get(child.get("id"))
                if el is not None and el.get("type") == "sparse_brdf":
                    direct[child.get("id")] = direct.get(child.get("id"), 0) + 1
                    props = _props(el)
                    if props is not None:
                        out.append((shape, child, props))
    # a material also referred to from elsewhere (a wrapper, a second reference outside
    # shapes) keeps its own BSDF
    return [c for c in out if c[1].tag != "ref" or refs[c[1].get("id")] == direct[c[1].get(
        "id")]]


def _group_key(props: dict, scene_dir: Path, file_key, seen: dict) -> tuple | None:
    """What the materials of one library share: ``file_key`` of the file (read once per
    file), its ensemble property, sampling and interpolation; None for a file that
    cannot be read (its ``sparse_brdf`` reports that)."""
    name = props["filename"]
    if name not in seen:
        path = Path(name) if Path(name).is_absolute() else scene_dir / name
        try:
            seen[name] = (file_key(path), str(path))
        except Exception:  # noqa: BLE001 - left to the material's own plugin
            seen[name] = None
    if seen[name] is None:
        return None
    props["filename"] = seen[name][1]
    return (seen[name][0], props.get("ensemble"), props.get("sampling"),
            props.get("interpolate", "false").lower())


def to_libraries(root: ET.Element, scene_dir: Path, file_key: Callable[[Path], object],
                 min_materials: int | None = None,
                 memory_budget: float | None = None) -> list[str]:
    """Rewrite the scene ``root`` (its ``<include>``s inlined, as
    :func:`~sparse_brdf.evaluation.scenes.replaced_materials` gives it; relative file
    names are the folder ``scene_dir``'s) in place: see the module docstring.
    ``file_key(path)``: what the files of one library share (their ensemble and grid:
    :func:`mitsuba_plugin.loading.library_key`). Returns one line per library written
    (for Mitsuba's log). ``min_materials``: the fewest materials a library serves
    (None: :data:`LIBRARY_MIN_MATERIALS`). ``memory_budget`` (MiB): the library's, for
    the grouped decoder's tables (None: the smallest its materials state, else none)."""
    groups: dict[tuple, list] = {}
    seen: dict = {}
    found = _candidates(root)
    if min_materials is None:
        min_materials = LIBRARY_MIN_MATERIALS
    if len({p["filename"] for _, _, p in found}) < min_materials:
        return []  # (no file read: a scene of a few materials loads as before)
    for shape, elem, props in found:
        key = _group_key(props, Path(scene_dir), file_key, seen)
        if key is not None:
            groups.setdefault(key, []).append((shape, elem, props))
    lines, written = [], 0
    for key, members in groups.items():
        files = list(dict.fromkeys(p["filename"] for _, _, p in members))
        if len(files) < min_materials:
            continue
        lib_id = f"{LIBRARY_ID}{written}"
        lib = ET.Element("bsdf", {"type": "sparse_library", "id": lib_id})
        ET.SubElement(lib, "string", {"name": "filenames", "value": ",".join(files)})
        for name in ("ensemble", "sampling"):
            value = members[0][2].get(name)
            if value is not None:
                if name == "ensemble" and not Path(value).is_absolute():
                    value = str(Path(scene_dir) / value)
                ET.SubElement(lib, "string", {"name": name, "value": value})
        ET.SubElement(lib, "boolean", {"name": "interpolate", "value": key[3]})
        stated = [float(p["memory_budget"]) for _, _, p in members if "memory_budget" in p]
        budget = memory_budget if memory_budget is not None else min(stated, default=None)
        if budget is not None:
            ET.SubElement(lib, "float", {"name": "memory_budget", "value": str(budget)})
        root.insert(_first_shape(root), lib)
        index = {f: i for i, f in enumerate(files)}
        dropped = set()
        for shape, elem, props in members:
            at = list(shape).index(elem)
            shape.remove(elem)
            shape.insert(at, ET.Element("ref", {"id": lib_id}))
            tex = ET.SubElement(shape, "texture", {"name": "sbrdf_index", "type": "uniform"})
            ET.SubElement(tex, "float", {"name": "value", "value": str(index[props["filename"]])})
            if elem.tag == "ref":
                dropped.add(elem.get("id"))
        for el in [el for el in root if el.tag == "bsdf" and el.get("id") in dropped]:
            root.remove(el)
        lines.append(f"sparse_brdf: {len(files)} materials on {len(members)} shapes served "
                     f"by one sparse_library ({lib_id}): the scene traces one BSDF for them")
        written += 1
    return lines


def _first_shape(root: ET.Element) -> int:
    """Where a library goes: before the scene's first shape."""
    return next((i for i, el in enumerate(root) if el.tag == "shape"), len(root))
