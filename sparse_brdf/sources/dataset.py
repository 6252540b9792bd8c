"""Training tensors: every material under each transform, each channel a separate tensor."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..coords import MERL_SHAPE
from ..transforms import TRANSFORMS, forward
from .corpora import Material


def training_tensors(
    materials: Sequence[Material],
    transforms: Sequence[str] = TRANSFORMS,
    shape: tuple[int, int, int] = MERL_SHAPE,
    progress: bool = True,
) -> tuple[np.ndarray, list[str]]:
    """Stack transformed channels of ``materials`` into an (N, n1, n2, n3) float32 array.

    N = len(materials) * len(transforms) * 3. Returns the array and one label per tensor,
    ``"<corpus>/<name>:<transform>:<channel>"``.
    """
    n = len(materials) * len(transforms) * 3
    x = np.empty((n, *shape), np.float32)
    labels: list[str] = []
    it = materials
    if progress:
        from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `import sparse_brdf`

        it = tqdm(materials, desc="load", unit="brdf")
    i = 0
    for m in it:
        brdf = m.load(shape)
        rho = brdf.channel_first()
        for t in transforms:
            x[i : i + 3] = forward(rho, t, brdf.valid)
            labels += [f"{m.corpus}/{m.name}:{t}:{c}" for c in "RGB"]
            i += 3
    return x, labels
