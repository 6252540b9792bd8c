"""The sparse model of one BRDF: per channel, a dictionary index and nonzero coefficients."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..brdf import BRDF
from ..coords import dirs_to_bins, geometric_valid
from ..errors import EnsembleMismatchError, InvalidBRDFError, short
from ..parallel import parallel_map
from ..transforms import (
    check_basis,
    check_floor,
    check_gain,
    check_lobe,
    check_transform,
    from_basis,
    inverse,
    inverse_at_bins,
)
from .ensemble import Ensemble
from .tensor import reconstruct_sparse

#: The largest transformed value of a float32 BRDF, ln(1 + float32 max) (both transforms;
#: cos_i cos_o <= 1). The coded channels are orthonormal maps of the transformed R, G, B
#: (dictionaries and colour basis), so a channel's sum of s^2 is at most 3 n T_MAX^2 on
#: a grid of n bins: larger coefficients are refused as corrupt.
T_MAX = float(np.log1p(np.float64(np.finfo(np.float32).max)))


@dataclass
class SparseBRDF:
    """A BRDF encoded over an ensemble (Tongbuasirilai et al., "A Sparse Non-parametric
    BRDF Model"; stored as in ``docs/file-format.md``).

    Long because it is the coded material's one data type: its checks and its three
    decodings (the coded tensor, the transformed table, the BRDF) and its evaluation at
    direction pairs share the same per-channel arithmetic, and each is short.

    Attributes
    ----------
    transform : str
        ``"log-plus"`` or ``"log-plus-cosine"``: the domain the coefficients code.
    shape : tuple of int
        The grid (n1, n2, n3), e.g. (90, 90, 180).
    ensemble_id : str
        Content hash of the ensemble the coefficients refer to.
    dict_index : ndarray of shape (3,), int
        Dictionary of each coded channel.
    locations : list of 3 int64 arrays of shape (T_c,)
        Flat coefficient indices a * n2 * n3 + b * n3 + c, sorted by decreasing |value|.
    values : list of 3 float32 arrays of shape (T_c,)
        The coefficients, in the transformed domain.
    name : str
        The material's name.
    stats : dict
        Encoding statistics (errors per transform, budget, options); not stored in files.
    basis : str
        Colour basis of the coded channels: ``"rgb"`` (channels are R, G, B) or
        ``"opponent"`` (channels are ``transforms.colour_matrix("opponent")`` times the
        transformed R, G, B; decoding mixes them back before the inverse transform).
    gain : float
        The material's gain 1/L (sr) for the level and lobe transforms
        (``transforms.material_gain``, stored in the file); 1 for the others.
    lobe : tuple of 7 floats or None
        The material's base lobe for the lobe transforms (alpha, kd and ks per channel,
        ``transforms.fit_base_lobe``, stored in the file as float16); None for the others.
    floor : float
        The material's floor f for the floor transforms: decoded values below f L
        (1/sr) are 0 (one of ``transforms.FLOORS``, chosen by the encoder, stored in the
        file as float16); 0 for the others.

    Raises
    ------
    InvalidBRDFError
        On construction, for locations outside the grid, mismatched locations and values,
        NaN/inf coefficients or coefficients larger than any finite BRDF's.
    ValueError
        For an unknown transform or colour basis.
    """

    transform: str
    shape: tuple[int, int, int]
    ensemble_id: str
    dict_index: np.ndarray
    locations: list[np.ndarray]
    values: list[np.ndarray]
    name: str = "brdf"
    stats: dict = field(default_factory=dict)
    basis: str = "rgb"
    gain: float = 1.0
    lobe: tuple[float, ...] | None = None
    floor: float = 0.0

    def __post_init__(self) -> None:
        check_transform(self.transform)
        check_basis(self.basis)
        self.gain = check_gain(self.transform, self.gain)
        self.lobe = check_lobe(self.transform, self.lobe)
        self.floor = check_floor(self.transform, self.floor)
        self.shape = tuple(int(n) for n in self.shape)  # type: ignore[assignment]
        self.dict_index = np.asarray(self.dict_index, np.int64).reshape(3)
        self.locations = [np.asarray(a, np.int64).reshape(-1) for a in self.locations]
        self.values = [np.asarray(v, np.float32).reshape(-1) for v in self.values]
        size = int(np.prod(self.shape))
        for c, (a, v) in enumerate(zip(self.locations, self.values, strict=True)):
            if a.shape != v.shape:
                raise InvalidBRDFError(f"{self.name}: channel {c} has {a.size} locations "
                                       f"and {v.size} values")
            if a.size and (a.min() < 0 or a.max() >= size):
                raise InvalidBRDFError(f"{self.name}: channel {c} has coefficient locations "
                                       f"outside the {self.shape} grid")
            if not np.all(np.isfinite(v)):
                raise InvalidBRDFError(f"{self.name}: channel {c} has NaN/inf coefficients")
            if np.unique(a).size != a.size:  # a file could not say which one holds
                raise InvalidBRDFError(f"{self.name}: channel {c} repeats a coefficient "
                                       "location")
            if float(np.sum(np.square(v, dtype=np.float64))) > 3.0 * size * T_MAX**2:
                raise InvalidBRDFError(
                    f"{self.name}: channel {c}'s coefficients (largest |s| "
                    f"{float(np.abs(v).max()):.3g}) are larger than any finite BRDF's")

    def __repr__(self) -> str:
        return (f"SparseBRDF({short(self.name)!r}, shape={self.shape}, "
                f"transform={self.transform!r}, basis={self.basis!r}, "
                f"coefficients={self.n_coeffs.tolist()}, "
                f"dictionaries={self.dict_index.tolist()}, ensemble={self.ensemble_id[:8]})")

    @property
    def n_coeffs(self) -> np.ndarray:
        """Nonzero coefficients per channel, shape (3,)."""
        return np.array([a.size for a in self.locations])

    def modes(self, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-mode atom indices of one channel's coefficients.

        Parameters
        ----------
        c : int
            The coded channel, 0, 1 or 2.

        Returns
        -------
        tuple of 3 numpy.ndarray
            (a_t, b_t, c_t), each of shape (T_c,): the atoms of modes 1, 2 and 3 of
            every coefficient, in the order of ``locations[c]``.
        """
        return np.unravel_index(self.locations[c], self.shape)

    def check_ensemble(self, ensemble: Ensemble) -> None:
        """Check that ``ensemble`` is the one these coefficients were encoded over.

        Parameters
        ----------
        ensemble : Ensemble
            The ensemble to decode with.

        Raises
        ------
        EnsembleMismatchError
            If its id differs from :attr:`ensemble_id`, a dictionary index is out of its
            range, or its grid differs from :attr:`shape`.
        """
        if ensemble.id != self.ensemble_id:
            raise EnsembleMismatchError(
                f"{self.name}: encoded with ensemble {self.ensemble_id}, but ensemble "
                f"{ensemble.id} was given: give the file's own ensemble (--ensemble "
                "FILE.npz), or re-encode the material with this one (sparse-brdf encode "
                f"SOURCE -o NEW.sbrdf --ensemble {ensemble.id})")
        if int(self.dict_index.max()) >= ensemble.n_dicts or int(self.dict_index.min()) < 0:
            raise EnsembleMismatchError(f"{self.name}: dictionary index out of range")
        if tuple(ensemble.shape) != tuple(self.shape):
            raise EnsembleMismatchError(
                f"{self.name}: grid {'x'.join(map(str, self.shape))}, but its ensemble's is "
                f"{'x'.join(map(str, ensemble.shape))}")

    def coded(self, ensemble: Ensemble) -> np.ndarray:
        """Reconstruct the coded channels, as the dictionaries see them.

        Parameters
        ----------
        ensemble : Ensemble
            The encoding ensemble.

        Returns
        -------
        numpy.ndarray
            float32, shape (3, n1, n2, n3): the channels in :attr:`basis`, transformed
            domain.

        Raises
        ------
        EnsembleMismatchError
            As :meth:`check_ensemble`.
        """
        self.check_ensemble(ensemble)

        def channel(c):
            return reconstruct_sparse(self.locations[c], self.values[c], self.shape,
                                      *ensemble.dictionary(int(self.dict_index[c])))

        return np.stack(list(parallel_map(channel, range(3))))

    def transformed(self, ensemble: Ensemble) -> np.ndarray:
        """Reconstruct the transformed R, G, B tensor (a full decode, before the inverse
        transform).

        Parameters
        ----------
        ensemble : Ensemble
            The encoding ensemble.

        Returns
        -------
        numpy.ndarray
            float32, shape (3, n1, n2, n3), in the domain of :attr:`transform`.

        Raises
        ------
        EnsembleMismatchError
            As :meth:`check_ensemble`.
        """
        return from_basis(self.coded(ensemble), self.basis)

    def decode(self, ensemble: Ensemble, valid: np.ndarray | None = None) -> BRDF:
        """Decode to the full tabulated BRDF.

        Parameters
        ----------
        ensemble : Ensemble
            The encoding ensemble.
        valid : numpy.ndarray, optional
            Bool (n1, n2, n3): the bins the result marks valid (its other bins are 0);
            default: the grid's geometric validity (both directions above the horizon).

        Returns
        -------
        BRDF
            Linear RGB values (n1, n2, n3, 3) in 1/sr, clamped to >= 0.

        Raises
        ------
        EnsembleMismatchError
            As :meth:`check_ensemble`.
        """
        rho = inverse(self.transformed(ensemble), self.transform, self.gain, self.lobe,
                      self.floor)
        mask = geometric_valid(self.shape) if valid is None else valid
        return BRDF(np.moveaxis(rho, 0, -1), mask, name=self.name, source="sparse")

    def eval(self, ensemble: Ensemble, wi: np.ndarray, wo: np.ndarray,
             chunk: int = 8192) -> np.ndarray:
        """BRDF values at direction pairs, from the nonzero terms only.

        Evaluates sum_t s_t U1[i, a_t] U2[j, b_t] U3[k, c_t] at the bins of the pairs (the
        same lookup as the tabulated BRDF), without building the tensor.

        Parameters
        ----------
        ensemble : Ensemble
            The encoding ensemble.
        wi, wo : numpy.ndarray
            Unit directions in the local shading frame (z up), shape (N, 3).
        chunk : int
            Pairs evaluated at a time (bounds the memory used).

        Returns
        -------
        numpy.ndarray
            float32, shape (N, 3): linear RGB values in 1/sr; 0 for pairs with a
            direction below the horizon, or in a bin whose lower-edge angles are.

        Raises
        ------
        EnsembleMismatchError
            As :meth:`check_ensemble`.
        """
        self.check_ensemble(ensemble)
        wi = np.asarray(wi, np.float64).reshape(-1, 3)
        wo = np.asarray(wo, np.float64).reshape(-1, 3)
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        up = np.array([0.0, 0.0, 1.0])
        bins = dirs_to_bins(np.where(above[:, None], wi, up), np.where(above[:, None], wo, up),
                            self.shape)
        out = np.zeros((wi.shape[0], 3), np.float32)
        for c in range(3):
            u1, u2, u3 = ensemble.dictionary(int(self.dict_index[c]))
            a, b, k = self.modes(c)
            s = self.values[c]
            for lo in range(0, wi.shape[0], chunk):
                sl = slice(lo, lo + chunk)
                g = u1[bins[0][sl]][:, a] * u2[bins[1][sl]][:, b] * u3[bins[2][sl]][:, k]
                out[sl, c] = g @ s
        out = from_basis(out.T, self.basis)  # (3, N)
        rho = inverse_at_bins(out, self.transform, bins, self.shape, self.gain, self.lobe,
                              self.floor).T
        keep = above & geometric_valid(self.shape)[bins]  # as decode() and the plugins
        return np.where(keep[:, None], rho, 0.0).astype(np.float32)


__all__ = ["SparseBRDF"]
