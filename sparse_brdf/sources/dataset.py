"""Training tensors: every material under each transform, each channel a separate tensor."""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..coords import MERL_SHAPE, geometric_valid
from ..transforms import check_basis, check_transform, forward, to_basis
from .corpora import Material

#: The transforms an ensemble is trained for by default: the relative ones, which code dim
#: values with relative precision (``docs/method.md``, "Transforms"). The paper's
#: ensembles used ``transforms.PAPER_TRANSFORMS``.
TRAIN_TRANSFORMS: tuple[str, ...] = ("log-relative", "log-relative-cosine")

#: Names of the three coded channels of each colour basis (``transforms.COLOUR_BASES``).
CHANNEL_NAMES = {"rgb": ("R", "G", "B"), "opponent": ("L", "RG", "YB")}


@dataclass
class TrainingData:
    """Training tensors and what the trainer needs to know about them.

    ``x``: (N, n1, n2, n3) float32; ``labels``: one ``"<corpus>/<name>:<transform>:
    <channel>"`` per tensor; ``missing``: {tensor index: bool array of the grid}, the
    bins above the horizon that the material does not measure, only for the (rare)
    materials that have any; the tensors of one material share one array.
    """

    x: np.ndarray
    labels: list[str]
    missing: dict[int, np.ndarray] = field(default_factory=dict)
    basis: str = "rgb"
    transforms: tuple[str, ...] = TRAIN_TRANSFORMS

    def __repr__(self) -> str:
        return (f"TrainingData({self.x.shape[0]} tensors, grid={tuple(self.x.shape[1:])}, "
                f"basis={self.basis!r}, transforms={list(self.transforms)}, "
                f"{len(self.missing)} with unmeasured bins)")

    def digest(self) -> str:
        """The sha256 (hex) of everything the trainer reads: the tensors' bytes, their
        labels, basis and transforms, and the unmeasured-bin masks.

        Two runs whose digests match trained on bit-identical data, so their ensembles
        match for the same options, seed and thread count; the ``train`` command stores
        it in the ensemble's ``meta["data_sha256"]``. Tabulations made through Mitsuba
        can differ in their last bits between Mitsuba builds or machines, which this
        makes visible.
        """
        return _digest(self.x.shape, self.labels, self.basis, self.transforms, [self.x],
                       self.missing)


def _digest(shape, labels, basis, transforms, blocks, missing) -> str:
    """:meth:`TrainingData.digest` of the tensors given as consecutive ``blocks``."""
    h = hashlib.sha256()
    h.update(repr((tuple(shape), list(labels), basis, list(transforms))).encode())
    for b in blocks:
        h.update(np.ascontiguousarray(b, np.float32).tobytes())
    for i in sorted(missing):
        h.update(str(i).encode())
        h.update(np.packbits(missing[i]).tobytes())
    return h.hexdigest()


def training_data(
    materials: Sequence[Material],
    transforms: Sequence[str] = TRAIN_TRANSFORMS,
    shape: tuple[int, int, int] = MERL_SHAPE,
    progress: bool = True,
    basis: str = "rgb",
    symmetrize: bool | None = None,
) -> TrainingData:
    """Stack transformed channels of ``materials`` into an (N, n1, n2, n3) float32 array.

    N = len(materials) * len(transforms) * 3. Each material's three transformed channels
    are taken to the colour ``basis`` (``transforms.to_basis``: ``rgb`` keeps R, G, B,
    ``opponent`` codes luminance / red-green / yellow-blue), the channels the encoder codes
    in that basis. Invalid bins hold 0 (``transforms.forward``). ``symmetrize``: as
    :func:`~sparse_brdf.sources.load.load_brdf` (None: networks symmetrised; False: raw,
    as the ensembles trained before 2026-12-05 read them).
    """
    n = len(materials) * len(transforms) * 3
    labels = _labels(materials, transforms, basis)
    x = np.empty((n, *shape), np.float32)
    missing: dict[int, np.ndarray] = {}
    for i, block in _channel_blocks(materials, transforms, shape, progress, basis,
                                    symmetrize, missing):
        x[i : i + 3] = block
    return TrainingData(x, labels, missing, basis, tuple(transforms))


def training_digest(
    materials: Sequence[Material],
    transforms: Sequence[str] = TRAIN_TRANSFORMS,
    shape: tuple[int, int, int] = MERL_SHAPE,
    progress: bool = True,
    basis: str = "rgb",
    symmetrize: bool | None = None,
) -> str:
    """:meth:`TrainingData.digest` of :func:`training_data` with the same arguments,
    computed one material at a time (the tensors are never stacked: 36 MB at a time
    instead of 5.5 GB for the shipped ensemble's data)."""
    n = len(materials) * len(transforms) * 3
    labels = _labels(materials, transforms, basis)
    missing: dict[int, np.ndarray] = {}  # filled as the blocks go; _digest reads it last
    blocks = (b for _, b in _channel_blocks(materials, transforms, shape, progress, basis,
                                            symmetrize, missing))
    return _digest((n, *shape), labels, basis, transforms, blocks, missing)


def _labels(materials, transforms, basis) -> list[str]:
    """One ``"<corpus>/<name>:<transform>:<channel>"`` per tensor, in training order,
    after checking the basis and the transforms."""
    check_basis(basis)
    for t in transforms:
        check_transform(t)
    return [f"{m.corpus}/{m.name}:{t}:{c}" for m in materials for t in transforms
            for c in CHANNEL_NAMES[basis]]


def _channel_blocks(materials, transforms, shape, progress, basis, symmetrize, missing):
    """(index of the first tensor, its three coded channels (3, *shape)) per material and
    transform, in training order; a material's unmeasured bins above the horizon go to
    ``missing`` under each of its tensors' indices (one shared array)."""
    from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `import sparse_brdf`

    above = geometric_valid(shape)
    i = 0
    for m in tqdm(materials, desc="load", unit="brdf", disable=not progress):
        brdf = m.load(shape, symmetrize)
        rho = brdf.channel_first()
        holes = above & ~brdf.valid
        for t in transforms:
            if holes.any():
                missing.update({j: holes for j in range(i, i + 3)})
            yield i, to_basis(forward(rho, t, brdf.valid), basis)
            i += 3


def training_tensors(
    materials: Sequence[Material],
    transforms: Sequence[str] = TRAIN_TRANSFORMS,
    shape: tuple[int, int, int] = MERL_SHAPE,
    progress: bool = True,
    basis: str = "rgb",
) -> tuple[np.ndarray, list[str]]:
    """The tensors and labels of :func:`training_data` (without the missing-bin masks)."""
    d = training_data(materials, transforms, shape, progress, basis)
    return d.x, d.labels
