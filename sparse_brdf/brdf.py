"""The one BRDF type of the package: a tabulated isotropic BRDF on the MERL grid."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .coords import bin_edges, cos_io
from .errors import InvalidBRDFError, short


@dataclass
class BRDF:
    """A tabulated BRDF.

    Attributes
    ----------
    values : ndarray of shape (n_h, n_d, n_p, 3), float32
        Linear RGB BRDF values (1/sr); invalid bins hold 0.
    valid : ndarray of shape (n_h, n_d, n_p), bool
        Bins that hold a measurement with both directions above the horizon.
    name : str
        Short material name (e.g. ``"gold-metallic-paint"``).
    source : str
        Where it came from (a path, or ``mitsuba:<name>``).
    meta : dict
        Free-form provenance kept with the material (e.g. a tabulation's settings).

    Raises
    ------
    InvalidBRDFError
        On construction, if ``values`` is not (n_h, n_d, n_p, 3), ``valid`` does not
        match it, or the valid bins hold NaN, inf or negative values, or none is valid.
        Values on invalid bins are set to 0 and stored as float32.
    """

    values: np.ndarray
    valid: np.ndarray
    name: str = "brdf"
    source: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        v = np.asarray(self.values)
        if v.ndim != 4 or v.shape[-1] != 3:
            raise InvalidBRDFError(
                f"{self.name}: BRDF values must have shape (n_h, n_d, n_p, 3), got {v.shape}"
            )
        valid = np.asarray(self.valid, dtype=bool)
        if valid.shape != v.shape[:3]:
            raise InvalidBRDFError(
                f"{self.name}: valid mask has shape {valid.shape}, expected {v.shape[:3]}"
            )
        v = np.where(valid[..., None], v, np.float32(0.0)).astype(np.float32, copy=False)
        # two reductions instead of two boolean arrays: NaN makes min() NaN, so the test
        # fails on NaN, inf or a negative value; then tell which
        if v.size and not (v.min() >= 0 and v.max() < np.inf):
            if not np.all(np.isfinite(v)):
                raise InvalidBRDFError(f"{self.name}: BRDF values contain NaN or inf")
            raise InvalidBRDFError(f"{self.name}: BRDF values are negative on valid bins")
        if not valid.any():
            raise InvalidBRDFError(f"{self.name}: the BRDF has no valid bin")
        self.values = v
        self.valid = valid

    def __repr__(self) -> str:
        src = f", source={short(self.source)!r}" if self.source else ""
        return (f"BRDF({short(self.name)!r}, shape={self.shape}, "
                f"valid={int(self.valid.sum())}/{self.valid.size} bins{src})")

    @property
    def shape(self) -> tuple[int, int, int]:
        """Grid shape (n_h, n_d, n_p)."""
        return tuple(self.values.shape[:3])  # type: ignore[return-value]

    def channel_first(self) -> np.ndarray:
        """The values channel-first.

        Returns
        -------
        numpy.ndarray
            A contiguous float32 copy of shape (3, n_h, n_d, n_p) (the layout the
            transforms and the encoder work in).
        """
        return np.ascontiguousarray(np.moveaxis(self.values, -1, 0))

    def albedo(self) -> np.ndarray:
        """Albedo estimate: rho cos(theta_o) integrated over the outgoing hemisphere,
        averaged (cosine-weighted) over the incident one.

        The integral uses the grid's own quadrature in half/difference angles
        (:func:`hemispherical_albedo`, bins evaluated at their centres).

        Returns
        -------
        numpy.ndarray
            float64, shape (3,): the RGB albedo (dimensionless); a lossless white
            Lambertian surface gives about 1.
        """
        return hemispherical_albedo(self.values, self.valid)

    def summary(self) -> dict:
        """A JSON-ready description (what ``sparse-brdf info`` prints).

        Returns
        -------
        dict
            ``name``, ``source``, ``shape`` ([n_h, n_d, n_p]), ``valid_bins``,
            ``total_bins``, and per RGB channel over the valid bins ``min``, ``max`` and
            ``mean`` (1/sr) and ``albedo`` (see :meth:`albedo`).
        """
        v = self.values[self.valid]
        return {
            "name": self.name,
            "source": self.source,
            "shape": list(self.shape),
            "valid_bins": int(self.valid.sum()),
            "total_bins": int(self.valid.size),
            "min": [float(x) for x in v.min(axis=0)],
            "max": [float(x) for x in v.max(axis=0)],
            "mean": [float(x) for x in v.mean(axis=0)],
            "albedo": [float(x) for x in self.albedo()],
        }


def hemispherical_albedo(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Bi-hemispherical albedo of tabulated values.

    (1/pi) * integral over wi, wo of rho cos_i cos_o, written in half/difference angles:
    d(wi) d(wo) = 4 cos(theta_d) sin(theta_h) sin(theta_d) d(theta_h) d(phi_h)
    d(theta_d) d(phi_d). phi_h integrates to 2 pi, and phi_d covers [0, pi) of [0, 2 pi)
    (reciprocity), so a factor 2. Bins are evaluated at their centres in each angle.

    Parameters
    ----------
    values : numpy.ndarray
        Linear BRDF values (n_h, n_d, n_p, 3), 1/sr.
    valid : numpy.ndarray
        Bool (n_h, n_d, n_p): the bins integrated over.

    Returns
    -------
    numpy.ndarray
        Shape (3,): the RGB albedo (dimensionless).
    """
    shape = values.shape[:3]
    n_h, n_d, n_p = shape
    th_edges = bin_edges(shape)[0]
    th = 0.5 * (th_edges[1:] + th_edges[:-1])
    dth = np.diff(th_edges)
    td = (np.arange(n_d) + 0.5) / n_d * (np.pi / 2)
    pd = (np.arange(n_p) + 0.5) / n_p * np.pi
    TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
    ci, co = cos_io(TH, TD, PD)
    w = (
        4.0 * np.cos(TD) * np.sin(TH) * np.sin(TD)
        * dth[:, None, None] * (np.pi / 2 / n_d) * (np.pi / n_p) * 2.0 * (2.0 * np.pi)
    )
    w = w * np.clip(ci, 0, None) * np.clip(co, 0, None) * valid
    return (values * w[..., None]).sum(axis=(0, 1, 2)) / np.pi

