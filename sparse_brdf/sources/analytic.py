"""Tabulating Mitsuba 3 BSDFs on the MERL grid through ``mi.BSDF.eval``.

Mitsuba's ``eval`` returns the BSDF times the cosine of the outgoing direction; that
cosine is divided out here. Directions come from the bins' lower-edge angles, as for
every other source, so all sources share one lookup convention.
"""

from __future__ import annotations

import numpy as np

from ..brdf import BRDF
from ..coords import MERL_SHAPE, angles_to_dirs, geometric_valid, grid_angles
from ..errors import InvalidBRDFError
from ..mitsuba_env import DEFAULT_VARIANT, variant


def tabulate_mitsuba(
    bsdf: dict,
    name: str = "mitsuba",
    shape: tuple[int, int, int] = MERL_SHAPE,
    variant_name: str = DEFAULT_VARIANT,
) -> BRDF:
    """Tabulate a Mitsuba BSDF given as a ``mi.load_dict`` dictionary.

    Returns a :class:`BRDF` of float32 linear RGB values on ``shape``; bins below the
    horizon are invalid.
    """
    import drjit as dr  # lazy: Dr.Jit and Mitsuba are slow to import
    import mitsuba as mi

    valid = geometric_valid(shape)
    th, td, pd = grid_angles(shape)
    wi, wo = angles_to_dirs(th[valid], td[valid], pd[valid])
    with variant(variant_name):
        try:
            obj = mi.load_dict(dict(bsdf))
        except Exception as exc:
            raise InvalidBRDFError(f"{name}: Mitsuba could not load BSDF {bsdf}: {exc}") from exc
        n = wi.shape[0]
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = mi.Vector3f(wi.T.astype(np.float32))
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        ctx = mi.BSDFContext()
        f = np.array(obj.eval(ctx, si, mi.Vector3f(wo.T.astype(np.float32))), dtype=np.float64)
    f = f.reshape(3, -1).T / np.maximum(wo[:, 2:3], 1e-12)
    values = np.zeros((*shape, 3), np.float32)
    values[valid] = np.maximum(f, 0.0)
    return BRDF(values=values, valid=valid, name=name, source=f"mitsuba:{name}")
