"""Dictionary ensembles: the learned bases of the model.

Tongbuasirilai et al., "A Sparse Non-parametric BRDF Model"; ``docs/method.md``,
"Training". An :class:`Ensemble` holds K dictionaries, each three orthonormal mode
matrices ``U1[k]`` (n1, n1), ``U2[k]`` (n2, n2), ``U3[k]`` (n3, n3), and the training
sparsity of each. :func:`resolve_ensemble` turns "an ensemble, a path or nothing" into an
ensemble (nothing: the shipped default, or the shipped ensemble a coefficient file names;
each read once per process). The trainer is :mod:`sparse_brdf.training.train`.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import BRDFFileError, EnsembleMismatchError, MissingDataError
from ..fileio import atomic_write, require_file
from ..paths import DEFAULT_ENSEMBLE_ID, ENSEMBLES_DIR
from ..transforms import PAPER_TRANSFORMS, TRANSFORMS


@dataclass
class Ensemble:
    """K dictionaries of orthonormal mode matrices.

    Long because it is the ensemble's one data type: its checks, identity (content hash),
    file format (save, load) and the shipped ensembles' lookup belong to it, and each is
    short.

    Attributes
    ----------
    u1, u2, u3 : ndarray of shape (K, n1, n1), (K, n2, n2), (K, n3, n3), float32
        The mode matrices of the K dictionaries (orthonormal columns: the atoms of the
        theta_h, theta_d and phi_d modes).
    taus : ndarray of shape (K,), int
        Training sparsity of each dictionary (0 when not trained under sparsity).
    meta : dict
        Provenance (data, parameters, seed, time taken); not part of the identity.

    Raises
    ------
    ValueError
        On construction, if the mode matrices are not square stacks of one K, or
        ``taus`` does not have K entries.
    """

    u1: np.ndarray
    u2: np.ndarray
    u3: np.ndarray
    taus: np.ndarray
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.u1 = np.ascontiguousarray(self.u1, np.float32)
        self.u2 = np.ascontiguousarray(self.u2, np.float32)
        self.u3 = np.ascontiguousarray(self.u3, np.float32)
        self.taus = np.asarray(self.taus, np.int64).reshape(-1)
        k = self.u1.shape[0]
        for name, u in (("u1", self.u1), ("u2", self.u2), ("u3", self.u3)):
            if u.ndim != 3 or u.shape[0] != k or u.shape[1] != u.shape[2]:
                raise ValueError(f"ensemble {name} must have shape (K, n, n) with K={k}, "
                                 f"got {u.shape}")
        if self.taus.shape != (k,):
            raise ValueError(f"ensemble taus must have shape ({k},), got {self.taus.shape}")
        self._id: str | None = None

    def __repr__(self) -> str:
        taus = sorted({int(t) for t in self.taus})
        shown = ", ".join(map(str, taus[:8])) + (", ..." if len(taus) > 8 else "")
        nbytes = self.u1.nbytes + self.u2.nbytes + self.u3.nbytes
        return (f"Ensemble(id={self.id[:8]}, {self.n_dicts} dictionaries, shape={self.shape}, "
                f"taus=[{shown}], {nbytes / 1e6:.1f} MB)")

    @property
    def n_dicts(self) -> int:
        return int(self.u1.shape[0])

    @property
    def transforms(self) -> tuple[str, ...]:
        """The transforms this ensemble was trained for (``meta["transforms"]``), from
        which :func:`~sparse_brdf.coding.spec.auto_transforms` decides what an ``auto``
        encoding chooses among. The paper's two where the provenance does not say
        (ensembles built by hand, or trained before the relative transforms)."""
        names = self.meta.get("transforms")
        if not names and "parts" in self.meta:  # a union: the parts' transforms
            names = [t for part in self.meta["parts"] for t in part.get("transforms", [])]
        known = [t for t in dict.fromkeys(names or ()) if t in TRANSFORMS]
        return tuple(known) or PAPER_TRANSFORMS

    @property
    def shape(self) -> tuple[int, int, int]:
        """Grid shape (n1, n2, n3) the ensemble represents."""
        return (self.u1.shape[1], self.u2.shape[1], self.u3.shape[1])

    @property
    def id(self) -> str:
        """Content hash (32 hex digits) of the mode matrices: what coefficient files name."""
        if self._id is None:
            h = hashlib.sha256()
            for u in (self.u1, self.u2, self.u3):
                h.update(np.asarray(u.shape, "<i8").tobytes())
                h.update(np.ascontiguousarray(u, "<f4").tobytes())
            self._id = h.hexdigest()[:32]
        return self._id

    def dictionary(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The mode matrices of one dictionary.

        Parameters
        ----------
        k : int
            The dictionary, in [0, K).

        Returns
        -------
        tuple of 3 numpy.ndarray
            (U1[k], U2[k], U3[k]), float32, of shapes (n1, n1), (n2, n2), (n3, n3).
        """
        return self.u1[k], self.u2[k], self.u3[k]

    def orthonormality_error(self) -> float:
        """How far the mode matrices are from orthonormal.

        Returns
        -------
        float
            The largest |U^T U - I| entry over every dictionary and mode (float64
            products); about 1e-7 for a float32 ensemble.
        """
        err = 0.0
        for u in (self.u1, self.u2, self.u3):
            g = np.einsum("kij,kil->kjl", u.astype(np.float64), u.astype(np.float64))
            err = max(err, float(np.abs(g - np.eye(u.shape[1])).max()))
        return err

    def union(self, other: Ensemble) -> Ensemble:
        """This ensemble's dictionaries followed by ``other``'s.

        Parameters
        ----------
        other : Ensemble
            An ensemble of the same grid.

        Returns
        -------
        Ensemble
            The K + K' dictionaries (a new id; files encoded over either part do not
            decode with it); ``meta`` holds both parts' provenance.

        Raises
        ------
        EnsembleMismatchError
            If the grids differ.
        """
        if other.shape != self.shape:
            raise EnsembleMismatchError(f"cannot unite ensembles of grids {self.shape} and "
                                        f"{other.shape}")
        meta = {"parts": [self.meta, other.meta]}
        return Ensemble(
            np.concatenate([self.u1, other.u1]), np.concatenate([self.u2, other.u2]),
            np.concatenate([self.u3, other.u3]), np.concatenate([self.taus, other.taus]), meta,
        )

    def save(self, path: str | os.PathLike) -> Path:
        """Write the ensemble as an uncompressed ``.npz``, atomically (float32 dictionaries
        compress by only 8 %, and every command reads them: 2 ms uncompressed, 22 ms
        inflated).

        Parameters
        ----------
        path : str or path-like
            The file to write (``u1``, ``u2``, ``u3``, ``taus``, ``meta`` as JSON, ``id``).

        Returns
        -------
        pathlib.Path
            The file written; :meth:`load` reads it back.
        """
        path = Path(path)
        with atomic_write(path) as f:
            np.savez(f, u1=self.u1, u2=self.u2, u3=self.u3, taus=self.taus,
                                meta=json.dumps(self.meta), id=self.id)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> Ensemble:
        """Read an ensemble written by :meth:`save`.

        Parameters
        ----------
        path : str or path-like
            The ``.npz`` file.

        Returns
        -------
        Ensemble
            The ensemble, its content hash checked against the stored id.

        Raises
        ------
        FileNotFoundError
            If the file is missing.
        BRDFFileError
            If it is not an ensemble file or its content does not match its id.
        """
        path = require_file(path, "ensemble file")
        try:
            with np.load(path, allow_pickle=False) as z:
                ens = cls(z["u1"], z["u2"], z["u3"], z["taus"], json.loads(str(z["meta"])))
                stored_id = str(z["id"])
        except Exception as exc:  # noqa: BLE001 - numpy and zipfile raise many kinds
            raise BRDFFileError(f"{path}: not a sparse-brdf ensemble file "
                                f"({type(exc).__name__}: {exc})") from exc
        if stored_id != ens.id:
            raise BRDFFileError(f"{path}: ensemble content does not match its hash (corrupt)")
        return ens

    @classmethod
    def default(cls) -> Ensemble:
        """The ensemble used when none is given (``docs/ensemble.md``).

        Returns
        -------
        Ensemble
            The shipped default (``paths.DEFAULT_ENSEMBLE_ID``), read once per process and
            shared: every call returns the same instance, whose mode matrices and taus
            are read-only arrays.
        """
        return cls.shipped(DEFAULT_ENSEMBLE_ID)

    @classmethod
    def shipped(cls, ensemble_id: str) -> Ensemble:
        """A shipped ensemble by its content hash.

        Parameters
        ----------
        ensemble_id : str
            32 hex digits, one of :func:`shipped_ids` (the id a ``.sbrdf`` file names).

        Returns
        -------
        Ensemble
            The ensemble, read once per process, with read-only arrays.

        Raises
        ------
        EnsembleMismatchError
            If no shipped ensemble has that id (the message names it and the shipped
            ones).
        """
        return _load_shipped(str(ensemble_id))


def shipped_ids() -> list[str]:
    """Content hashes of the ensembles shipped in the package, the default first."""
    ids = sorted(p.stem for p in ENSEMBLES_DIR.glob("*.npz"))
    return sorted(ids, key=lambda i: i != DEFAULT_ENSEMBLE_ID)


@functools.cache
def _load_shipped(ensemble_id: str) -> Ensemble:
    """A shipped ensemble, with read-only arrays (not cached when it is missing)."""
    path = ENSEMBLES_DIR / f"{ensemble_id}.npz"
    if not path.is_file():
        if ensemble_id == DEFAULT_ENSEMBLE_ID:
            raise MissingDataError(f"{path}: the default ensemble is not installed (a "
                                   "broken install: reinstall sparse-brdf)")
        raise EnsembleMismatchError(
            f"ensemble {ensemble_id} is not shipped with this version (shipped: "
            f"{', '.join(shipped_ids()) or 'none'}); pass its file with --ensemble, or "
            "re-encode the material with a shipped one (sparse-brdf encode SOURCE -o "
            "NEW.sbrdf)")
    ens = Ensemble.load(path)
    if ens.id != ensemble_id:
        raise BRDFFileError(f"{path}: holds ensemble {ens.id}, not the {ensemble_id} its "
                            "name says")
    for a in (ens.u1, ens.u2, ens.u3, ens.taus):
        a.flags.writeable = False
    return ens


def resolve_ensemble(ensemble: Ensemble | str | os.PathLike | None = None,
                     for_id: str | None = None) -> Ensemble:
    """``ensemble`` itself, the ensemble file at that path, or the shipped ensemble with
    that id (32 hex digits, when no such file exists); without one (None or ""), the
    shipped ensemble ``for_id`` (the id a coefficient file names), else the shipped
    default (:meth:`Ensemble.default`)."""
    if isinstance(ensemble, Ensemble):
        return ensemble
    if ensemble is None or ensemble == "":
        return Ensemble.shipped(for_id) if for_id else Ensemble.default()
    if _is_id(str(ensemble)) and not Path(ensemble).exists():
        return Ensemble.shipped(str(ensemble))
    return Ensemble.load(ensemble)


def _is_id(text: str) -> bool:
    """Whether ``text`` looks like an ensemble id (32 lowercase hex digits)."""
    return len(text) == 32 and all(ch in "0123456789abcdef" for ch in text)
