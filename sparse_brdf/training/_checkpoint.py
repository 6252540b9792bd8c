"""Training checkpoints: what one sparsity's training has learned so far, written after
every iteration and read back to resume, under a fingerprint of the run it belongs to."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import BRDFFileError, UsageError
from ..fileio import atomic_write


@dataclass
class TrainState:
    """What one sparsity's training has learned so far (checkpointed every iteration)."""

    u1: np.ndarray  # (K, n1, n1)
    u2: np.ndarray
    u3: np.ndarray
    labels: np.ndarray  # (N,) cluster of each tensor
    codes_idx: np.ndarray  # (N, tau) flat coefficient indices, int32
    codes_val: np.ndarray  # (N, tau) coefficient values, float32
    errors: np.ndarray  # (N,) squared error of each tensor under its dictionary
    iteration: int = 0
    history: list = field(default_factory=list)
    init_seconds: float = 0.0  # time taken by the initialisation
    coded: bool = False  # the codes belong to the current dictionaries (a warm start's)


def run_options(extra: dict, masked: bool, init: str) -> dict | None:
    """What besides data, tau, K and seed defines a run (None: the first trainer's
    options, whose checkpoints keep their fingerprints); ``extra``: the unmeasured bins of
    each tensor that has any (``TensorStore.extra``)."""
    if not masked and init == "random":
        return None
    h = hashlib.sha256()
    for i in sorted(extra):
        h.update(np.asarray([i], "<i8").tobytes())
        h.update(np.asarray(extra[i], "<i8").tobytes())
    return {"masked": masked, "init": init, "missing": h.hexdigest()}


def fingerprint(x, norms, tau, n_dicts, seed, options: dict | None = None) -> str:
    """The hash a checkpoint is stored under: the tensors' shape and norms (float64),
    tau, K, the seed and :func:`run_options`."""
    h = hashlib.sha256(json.dumps([list(x.shape), tau, n_dicts, seed]).encode())
    h.update(np.asarray(norms, "<f8").tobytes())
    if options is not None:
        h.update(json.dumps(options, sort_keys=True).encode())
    return h.hexdigest()


def save_checkpoint(path, state: TrainState, run: str) -> None:
    """Write ``state`` to ``path`` (``.npz``, atomically) under the fingerprint ``run``."""
    with atomic_write(path) as f:
        np.savez(f, u1=state.u1, u2=state.u2, u3=state.u3, labels=state.labels,
                 codes_idx=state.codes_idx, codes_val=state.codes_val, errors=state.errors,
                 iteration=state.iteration, history=json.dumps(state.history),
                 init_seconds=state.init_seconds, fingerprint=run)


def load_checkpoint(path, run: str) -> TrainState | None:
    """The state checkpointed at ``path`` (None if there is no file); refuses a checkpoint
    of another run (another fingerprint ``run``) and an unreadable file."""
    path = Path(path)
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            stored = str(z["fingerprint"])
            state = None if stored != run else TrainState(
                z["u1"], z["u2"], z["u3"], z["labels"], z["codes_idx"], z["codes_val"],
                z["errors"], int(z["iteration"]), json.loads(str(z["history"])),
                float(z["init_seconds"]) if "init_seconds" in z else 0.0)
    except Exception as exc:  # noqa: BLE001 - numpy and zipfile raise many kinds
        raise BRDFFileError(f"{path}: not a readable training checkpoint "
                            f"({type(exc).__name__}: {exc}); delete it to redo its "
                            "sparsity") from exc
    if state is None:
        raise UsageError(f"{path}: checkpoint belongs to another training run "
                         "(different data, tau, K, seed, masking or initialisation); "
                         "delete it or use another folder")
    return state
