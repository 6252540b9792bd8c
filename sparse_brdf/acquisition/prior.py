"""The atom prior of encoding from samples: which atoms of each dictionary training
materials use, and with what values (``docs/method.md``, "Encoding from samples").

For every training material, transform and coded channel, the material is projected on
every dictionary of the ensemble (the full-table encoder's projection,
:func:`~sparse_brdf.coding.projection.project_all`) and its :data:`PRIOR_COEFFS` largest
coefficients kept. Per (transform, channel, dictionary) the pool is the
:data:`POOL_SIZE` atoms of largest mean squared value over the materials (a material
that does not keep an atom counts as 0 there), with that mean, the variance and the
fraction of the materials that kept it. The default prior (training materials of the
merl corpus's training split, computed on first use and cached on disk) is
:func:`sparse_brdf.acquisition.defaults.default_prior`.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass

import numpy as np

from ..coding.ensemble import Ensemble
from ..coding.projection import coded_channels, project_all
from ..coding.spec import ENCODE_OPTIONS
from ..fileio import atomic_write

#: Coefficients per material and dictionary that the prior sees.
PRIOR_COEFFS = 512
#: Atoms per (transform, channel, dictionary) in the pool.
POOL_SIZE = 1024
#: Version of the prior's computation (part of its cache key).
PRIOR_VERSION = 1


@dataclass
class AtomPrior:
    """Pools of atoms per transform, coded channel and dictionary.

    Attributes
    ----------
    ensemble_id : str
        The ensemble the locations refer to.
    transforms : tuple of str
        The transforms, the first axis of the arrays.
    loc : ndarray of shape (T, 3, K, P), int64
        Flat atom locations (C order of the grid), by decreasing mean squared value.
    mean, var, freq : ndarrays of shape (T, 3, K, P), float64
        Mean and variance of each atom's value over the training materials, and the
        fraction of them that kept it.
    materials : list of str
        The training materials' names.
    """

    ensemble_id: str
    transforms: tuple[str, ...]
    loc: np.ndarray
    mean: np.ndarray
    var: np.ndarray
    freq: np.ndarray
    materials: list[str]

    def pool(self, transform: str, channel: int, dictionary: int):
        """(loc, mean, var) of one pool, each (P,)."""
        t = self.transforms.index(transform)
        return (self.loc[t, channel, dictionary], self.mean[t, channel, dictionary],
                self.var[t, channel, dictionary])


def _aggregate(idx: list[np.ndarray], val: list[np.ndarray], m: int, p: int):
    """The pool of one (transform, channel, dictionary) from each material's kept
    coefficients: the ``p`` locations of largest mean squared value over ``m``
    materials, with mean, variance and frequency."""
    loc, inv = np.unique(np.concatenate(idx), return_inverse=True)
    v = np.concatenate(val).astype(np.float64)
    s1 = np.bincount(inv, v, loc.size) / m
    s2 = np.bincount(inv, v * v, loc.size) / m
    cnt = np.bincount(inv, minlength=loc.size) / m
    order = np.argsort(-s2, kind="stable")[:p]
    out = [loc[order], s1[order], np.maximum(s2[order] - s1[order] ** 2, 0.0), cnt[order]]
    if order.size < p:  # fewer distinct atoms than the pool: pad with unused atom 0
        out = [np.pad(a, (0, p - order.size)) for a in out]
    return out


def compute_prior(ens: Ensemble, brdfs: list, transforms: tuple[str, ...] | None = None,
                  coeffs: int = PRIOR_COEFFS, pool: int = POOL_SIZE) -> AtomPrior:
    """The atom prior of ``brdfs`` (BRDFs or corpus materials, loaded one at a time) on
    ``ens``, for ``transforms`` (default: those ``ens`` was trained for); a progress bar
    per material, whose estimate of the time left is the mean time per material so far
    (every material costs the same: one table, the same projections)."""
    from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `import sparse_brdf`

    basis = ENCODE_OPTIONS["basis"]
    transforms = tuple(transforms or ens.transforms)
    k = ens.n_dicts
    got = {(t, c, j): ([], []) for t in transforms for c in range(3) for j in range(k)}
    names = []
    for item in tqdm(brdfs, desc="atom prior", unit="material", leave=False, smoothing=0):
        b = item.load(ens.shape) if hasattr(item, "load") else item
        names.append(b.name)
        for t in transforms:
            p = project_all(b, ens, t, coeffs, y=coded_channels(b, t, basis))
            for c in range(3):
                for j in range(k):
                    got[t, c, j][0].append(p.idx[c][j])
                    got[t, c, j][1].append(p.val[c][j])
    arrays = [[[_aggregate(*got[t, c, j], len(names), pool) for j in range(k)]
               for c in range(3)] for t in transforms]
    a = [np.array([[[x[i] for x in ch] for ch in tr] for tr in arrays]) for i in range(4)]
    return AtomPrior(ens.id, tuple(transforms), a[0].astype(np.int64), a[1], a[2], a[3],
                     names)


def save_prior(path, prior: AtomPrior) -> None:
    """Write an atom prior as an ``.npz`` (atomically)."""
    with atomic_write(path) as f:
        np.savez(f, ensemble_id=prior.ensemble_id, transforms=np.array(prior.transforms),
                 loc=prior.loc, mean=prior.mean, var=prior.var, freq=prior.freq,
                 materials=np.array(prior.materials))


def load_prior(path) -> AtomPrior | None:
    """An atom prior written by :func:`save_prior`, or None if the file is absent or
    damaged."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return AtomPrior(str(z["ensemble_id"]), tuple(z["transforms"].tolist()),
                             z["loc"], z["mean"], z["var"], z["freq"],
                             z["materials"].tolist())
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return None
