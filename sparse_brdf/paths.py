"""Where the package's own files, its scenes and the shared measured data are found.

Everything the package ships is found from here, so a checkout, an editable install and a
wheel behave the same: the scenes live in the checkout's top-level ``scenes/`` and are
copied into the wheel as ``sparse_brdf/scenes`` (see ``pyproject.toml``).
"""

from __future__ import annotations

import os
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent
DATA_DIR = PACKAGE_DIR / "data"
#: Every shipped dictionary ensemble, one ``<id>.npz`` per ensemble (``sparse-brdf train``
#: writes files of this format), so that coefficient files find the ensemble they name.
ENSEMBLES_DIR = DATA_DIR / "ensembles"
#: The content hash of the ensemble used when none is given (docs/ensemble.md).
DEFAULT_ENSEMBLE_ID = "86741890fc36254718acbe579f21e55d"
DEFAULT_ENSEMBLE_PATH = ENSEMBLES_DIR / f"{DEFAULT_ENSEMBLE_ID}.npz"
#: The shipped ensemble trained for the paper's transforms (log-plus, log-plus-cosine):
#: the paper's encoder (``PAPER_OPTIONS``, ``--paper``) encodes over it when no other
#: ensemble is named (docs/ensemble.md).
PAPER_ENSEMBLE_ID = "5fea9b89b97e561857b3380fdef7d438"
#: fit-scene's calibration of its SNR proxy (written by ``benchmarks/calibrate.py``).
CALIBRATION_PATH = DATA_DIR / "snr_calibration.json"
#: Six measured ``merl`` test-split networks shipped for the demo (licence beside them).
DEMO_MATERIALS_DIR = DATA_DIR / "materials"
#: Bench configurations shipped with the package (``sparse-brdf bench NAME``).
CONFIGS_DIR = DATA_DIR / "configs"
#: Mitsuba scenes: inside the package when installed from a wheel, else the checkout's.
SCENES_DIR = next(
    (d for d in (PACKAGE_DIR / "scenes", PACKAGE_DIR.parent / "scenes") if d.is_dir()),
    PACKAGE_DIR.parent / "scenes",
)
#: Environment variable naming the shared data folder (holding ``nbrdf/`` and ``envmaps/``).
DATA_ENV = "SPARSE_BRDF_DATA"


def _shared_candidates() -> list[Path]:
    out = [Path(os.environ[DATA_ENV])] if os.environ.get(DATA_ENV) else []
    return out + [PACKAGE_DIR.parents[1] / "shared" / "data", Path.cwd().parent / "shared" / "data"]


def shared_data_dir() -> Path | None:
    """The shared data folder (``$SPARSE_BRDF_DATA`` or ``../shared/data``), or None."""
    return next((c for c in _shared_candidates() if (c / "nbrdf").is_dir()), None)


def shared_envmaps_dir() -> Path | None:
    """The shared environment maps (``<shared data>/envmaps``), or None when absent."""
    return next((c / "envmaps" for c in _shared_candidates() if (c / "envmaps").is_dir()), None)
