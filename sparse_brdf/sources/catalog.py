"""The built-in Mitsuba material catalogue (corpus ``mitsuba``): measured-IOR rough
conductors, rough plastics, principled paints with clearcoat and sheen, and diffuse
materials, each a ``mi.load_dict`` dictionary tabulated through ``mi.BSDF.eval``
(:mod:`sparse_brdf.sources.analytic`).
"""

from __future__ import annotations


def _conductors() -> dict[str, dict]:
    out = {}
    for mat, alphas in {
        "Au": (0.08, 0.25), "Cu": (0.12, 0.35), "Cr": (0.05, 0.2), "TiN": (0.15, 0.3),
        "Ag": (0.1, 0.4), "Al": (0.06, 0.3), "Ir": (0.18,), "W": (0.4,), "Mo": (0.22,),
        "Ta": (0.1,),
    }.items():
        for a in alphas:
            out[f"{mat.lower()}-ggx-{a:g}"] = {
                "type": "roughconductor", "material": mat, "alpha": a, "distribution": "ggx"}
    for mat, a in (("Au", 0.15), ("Cu", 0.07), ("Al", 0.2)):
        out[f"{mat.lower()}-beckmann-{a:g}"] = {
            "type": "roughconductor", "material": mat, "alpha": a, "distribution": "beckmann"}
    return out


def _rgb(c: tuple[float, float, float]) -> dict:
    return {"type": "rgb", "value": list(c)}


_COLOURS = {
    "red": (0.6, 0.08, 0.05), "green": (0.1, 0.45, 0.12), "blue": (0.05, 0.12, 0.55),
    "white": (0.8, 0.8, 0.78), "black": (0.02, 0.02, 0.025), "yellow": (0.7, 0.55, 0.08),
    "orange": (0.8, 0.3, 0.05), "grey": (0.25, 0.25, 0.25), "purple": (0.3, 0.08, 0.4),
}


def _plastics() -> dict[str, dict]:
    out = {}
    for (col, a, dist) in (
        ("red", 0.05, "ggx"), ("red", 0.3, "ggx"), ("green", 0.1, "ggx"), ("blue", 0.2, "ggx"),
        ("white", 0.08, "ggx"), ("black", 0.04, "ggx"), ("yellow", 0.15, "beckmann"),
        ("orange", 0.4, "ggx"), ("grey", 0.12, "beckmann"), ("purple", 0.25, "ggx"),
        ("black", 0.2, "beckmann"), ("white", 0.35, "ggx"),
    ):
        out[f"plastic-{col}-{dist}-{a:g}"] = {
            "type": "roughplastic", "diffuse_reflectance": _rgb(_COLOURS[col]),
            "alpha": a, "distribution": dist, "int_ior": 1.49}
    return out


def _principled() -> dict[str, dict]:
    out = {}
    for col, rough, metallic, cc, sheen in (
        ("red", 0.4, 0.0, 1.0, 0.0), ("blue", 0.3, 0.0, 0.7, 0.0), ("white", 0.5, 0.0, 1.0, 0.0),
        ("yellow", 0.35, 0.9, 0.6, 0.0), ("green", 0.3, 0.8, 0.8, 0.0),
        ("red", 0.9, 0.0, 0.0, 1.0), ("blue", 0.8, 0.0, 0.0, 1.0), ("white", 0.95, 0.0, 0.0, 0.8),
        ("purple", 0.7, 0.0, 0.0, 1.0), ("grey", 0.6, 0.5, 0.0, 0.0),
        ("orange", 0.25, 0.0, 0.0, 0.0), ("black", 0.2, 0.0, 1.0, 0.0),
    ):
        kind = "clearcoat" if cc else ("sheen" if sheen else "paint")
        if metallic:
            kind = "metallic-" + kind
        out[f"principled-{kind}-{col}-{rough:g}"] = {
            "type": "principled", "base_color": _rgb(_COLOURS[col]), "roughness": rough,
            "metallic": metallic, "clearcoat": cc, "clearcoat_gloss": 0.8, "sheen": sheen,
            "sheen_tint": 0.3, "specular": 0.5}
    return out


def _diffuse() -> dict[str, dict]:
    return {f"diffuse-{c}": {"type": "diffuse", "reflectance": _rgb(_COLOURS[c])}
            for c in ("white", "red", "grey", "green", "orange")}


def mitsuba_catalog() -> dict[str, dict]:
    """Every built-in analytic material (the ``mitsuba`` corpus).

    Returns
    -------
    dict of str to dict
        Name (e.g. ``"au-ggx-0.25"``) -> the Mitsuba 3 BSDF dictionary for ``mi.load_dict``:
        rough conductors, rough plastics, principled materials and diffuse surfaces (at
        least 40). ``load_brdf("mitsuba:<name>")`` tabulates one.
    """
    return {**_conductors(), **_plastics(), **_principled(), **_diffuse()}
