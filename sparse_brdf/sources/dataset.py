"""Training tensors: every material under each transform, each channel a separate tensor."""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..coords import MERL_SHAPE, geometric_valid
from ..fingerprints import (
    FINGERPRINT_STATS,
    fingerprint_changes,
    fingerprint_list,
)
from ..transforms import check_basis, check_transform, forward, to_basis
from .corpora import Material
from .load import source_key

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
        it in the ensemble's ``meta["data_sha256"]``, for information: numpy's SIMD
        kernels and Mitsuba's LLVM backend round differently on other CPUs, which changes
        it. :func:`training_fingerprint` tells a change of the data from that.
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


def training_fingerprint(
    materials: Sequence[Material],
    transforms: Sequence[str] = TRAIN_TRANSFORMS,
    shape: tuple[int, int, int] = MERL_SHAPE,
    progress: bool = True,
    basis: str = "rgb",
    symmetrize: bool | None = None,
    data: TrainingData | None = None,
) -> dict:
    """What an ensemble was trained on, in a form that tells a change of the data from
    the rounding that differs between machines (:mod:`sparse_brdf.fingerprints`).

    Parameters
    ----------
    materials, transforms, shape, progress, basis, symmetrize
        As :func:`training_data`.
    data : TrainingData, optional
        :func:`training_data` of the same arguments, when already computed; else the
        tensors are computed one material at a time (36 MB at a time instead of 5.5 GB
        for the shipped ensemble's data).

    Returns
    -------
    dict
        JSON-ready: ``inputs_sha256`` (exact: every material's inputs as
        :func:`~sparse_brdf.sources.load.source_key` reads them, the labels, transforms,
        basis, grid and symmetrisation), ``inputs`` ({material: its key}), ``settings``,
        ``tensors`` ({label: fingerprint list}, float64 statistics of each tensor, in
        the order of ``stats``), ``size`` (values per tensor), and
        ``data_sha256`` (:meth:`TrainingData.digest`: bit identity, for information).
        :func:`fingerprint_mismatches` compares two of them.
    """
    labels = _labels(materials, transforms, basis)
    inputs = {f"{m.corpus}/{m.name}": source_key(m.source, shape, symmetrize)
              for m in materials}
    settings = {"transforms": list(transforms), "basis": basis, "grid": list(shape),
                "symmetrize": symmetrize is not False}
    h = hashlib.sha256(json.dumps([inputs, settings, labels], sort_keys=True).encode())
    tensors: dict[str, list[float]] = {}
    if data is None:
        missing: dict[int, np.ndarray] = {}
        blocks = _channel_blocks(materials, transforms, shape, progress, basis, symmetrize,
                                 missing)
    else:
        missing = data.missing
        blocks = ((i, data.x[i : i + 3]) for i in range(0, len(data.x), 3))

    def fingerprinted(blocks):
        for i, block in blocks:
            for j, tensor in enumerate(block):
                tensors[labels[i + j]] = fingerprint_list(tensor)
            yield block

    digest = _digest((len(labels), *shape), labels, basis, transforms, fingerprinted(blocks),
                     missing)
    return {"inputs_sha256": h.hexdigest(), "inputs": inputs, "settings": settings,
            "stats": list(FINGERPRINT_STATS), "size": math.prod(shape),
            "tensors": tensors, "data_sha256": digest}


def fingerprint_mismatches(got: dict, want: dict) -> list[str]:
    """How two :func:`training_fingerprint` results differ, one line per difference.

    Parameters
    ----------
    got : dict
        The fingerprint of the data as computed now.
    want : dict
        The fingerprint stored when the ensemble was trained (``meta["data_fingerprint"]``).

    Returns
    -------
    list of str
        Empty when the data match: the same exact inputs, and every tensor's statistics
        within :data:`~sparse_brdf.fingerprints.FINGERPRINT_RTOL` of the scale of its
        material's channels in that transform
        (the largest L2 norm and magnitude of the three). Else a line per material whose
        inputs changed, per setting that changed, and per tensor (named
        ``"<corpus>/<name>:<transform>:<channel>"``) whose statistics moved, naming each
        statistic.
    """
    lines = []
    for key in ("settings", "stats", "size"):
        if got[key] != want[key]:
            lines.append(f"{key}: {want[key]} -> {got[key]}")
    for name in sorted(got["inputs"].keys() | want["inputs"].keys()):
        a, b = got["inputs"].get(name), want["inputs"].get(name)
        if a != b:
            lines.append(f"{name}: " + ("not in the stored data" if b is None else
                                        "missing now" if a is None else
                                        "its inputs changed (the source file's bytes, the "
                                        "BSDF's parameters or the Mitsuba version)"))
    if lines:
        return lines
    scales = _channel_scales(want)
    for label, fp in want["tensors"].items():
        moved = fingerprint_changes(got["tensors"][label], fp, want["size"],
                                    scale=scales[label.rpartition(":")[0]])
        if moved:
            lines.append(f"{label}: " + "; ".join(moved))
    return lines


def _channel_scales(fp: dict) -> dict[str, dict[str, float]]:
    """Per material and transform (``"<corpus>/<name>:<transform>"``), the largest L2
    norm and magnitude of its three channels: the scale each of them rounds at (an
    opponent colour channel is a difference of transformed R, G and B, and rounds as
    they do, however small it is)."""
    stats = fp["stats"]
    l2, top = stats.index("l2"), stats.index("max")
    scales: dict[str, dict[str, float]] = {}
    for label, f in fp["tensors"].items():
        s = scales.setdefault(label.rpartition(":")[0], {"l2": 0.0, "max": 0.0})
        s["l2"], s["max"] = max(s["l2"], abs(f[l2])), max(s["max"], abs(f[top]))
    return scales


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
