"""Named corpora of materials and their deterministic train/test split.

- ``mitsuba``: built into the package, always there: Mitsuba 3 BSDFs (measured-IOR
  rough conductors, rough plastics, principled paints with clearcoat and sheen,
  diffuse; :mod:`sparse_brdf.sources.catalog`), tabulated through ``mi.BSDF.eval``.
- ``merl``, ``rgl``: Neural-BRDF fits of measured MERL and RGL-EPFL materials, found in
  ``../shared/data/nbrdf`` (or ``$SPARSE_BRDF_DATA/nbrdf``) when present.
- any folder of ``.binary`` (MERL/DTU) or ``.h5`` (Neural-BRDF) files, given by path.

Split: within a corpus, materials are ranked by sha256("<corpus>/<name>") and the first
``round(0.15 * n)`` (at least 1) form the test split; the rest train. The rule depends
only on names, so adding a material never moves another one across the split.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

from ..brdf import BRDF
from ..coords import MERL_SHAPE
from ..errors import MissingDataError, MissingFileError, UsageError, short
from ..params import check_choice
from ..paths import DEMO_MATERIALS_DIR, shared_data_dir
from .catalog import mitsuba_catalog
from .load import load_brdf

TEST_FRACTION = 0.15


@dataclass(frozen=True)
class Material:
    """One named material of a corpus.

    Attributes
    ----------
    name : str
        The material's name within its corpus (e.g. ``"blue-acrylic"``).
    corpus : str
        The corpus it belongs to (e.g. ``"merl"``); ``"<corpus>/<name>"`` is its key.
    source : str
        What :func:`~sparse_brdf.load_brdf` reads: a file path or ``"mitsuba:<name>"``.
    """

    name: str
    corpus: str
    source: str  # a file path or "mitsuba:<name>"

    def load(self, shape: tuple[int, int, int] = MERL_SHAPE) -> BRDF:
        """Tabulate the material (cached on disk, see :func:`~sparse_brdf.load_brdf`).

        Parameters
        ----------
        shape : tuple of int
            The grid (n_h, n_d, n_p); default the MERL grid (90, 90, 180).

        Returns
        -------
        BRDF
            Its values on that grid, named :attr:`name`.
        """
        brdf = load_brdf(self.source, shape=shape)
        brdf.name = self.name
        return brdf


#: The splits of a corpus (``Corpus.split``; a bench's and the trainer's ``split``).
SPLITS: tuple[str, ...] = ("train", "test", "all")
#: The corpora the trainer reads unless told otherwise (``sparse-brdf train --corpus``).
TRAINING_CORPORA: tuple[str, ...] = ("merl", "rgl", "mitsuba")


@dataclass(frozen=True)
class Corpus:
    """A named set of materials with a fixed train/test split (:func:`get_corpus`).

    Attributes
    ----------
    name : str
        The corpus's name (``"mitsuba"``, ``"merl"``, ...), or a folder's name.
    description : str
        One line saying what it holds (as ``sparse-brdf corpus list`` prints it).
    materials : tuple of Material
        Every material, in name order.
    test_only : bool
        Every material is unseen (the split's train part is empty), e.g. the shipped
        demo materials.
    """

    name: str
    description: str
    materials: tuple[Material, ...]
    test_only: bool = False  # every material is unseen (e.g. the shipped demo materials)

    def __repr__(self) -> str:
        return (f"Corpus({short(self.name)!r}, {len(self.materials)} materials"
                f"{', test only' if self.test_only else ''})")

    def split(self, which: str = "all") -> list[Material]:
        """The materials of one split.

        Parameters
        ----------
        which : str
            ``"train"``, ``"test"`` or ``"all"`` (``SPLITS``). The test split is a fixed
            15 % of the names (at least one), chosen by a hash of corpus and name, so it
            does not change when materials are added; a test-only corpus has no
            training split.

        Returns
        -------
        list of Material
            In name order.

        Raises
        ------
        UsageError
            For a split not in ``SPLITS``.
        """
        if check_choice("split", which, SPLITS) == "all":
            return list(self.materials)
        if self.test_only:
            return list(self.materials) if which == "test" else []
        test = set(test_names(self.name, [m.name for m in self.materials]))
        return [m for m in self.materials if (m.name in test) == (which == "test")]


def test_names(corpus: str, names: list[str]) -> list[str]:
    """The test split of ``names``: round(15%) of them (>= 1), chosen by name hash."""
    if not names:
        return []
    ranked = sorted(names, key=lambda n: hashlib.sha256(f"{corpus}/{n}".encode()).hexdigest())
    n_test = max(1, round(TEST_FRACTION * len(names)))
    return sorted(ranked[:n_test])


def _folder_corpus(name: str, folder: Path, description: str) -> Corpus:
    files = sorted(p for p in folder.iterdir() if p.suffix in (".binary", ".h5"))
    mats = tuple(Material(p.stem, name, str(p)) for p in files)
    return Corpus(name, description, mats)


def _demo_corpus() -> Corpus:
    """Built-in ``merl-demo``: the shipped networks, all test materials of ``merl``; their
    keys are ``merl/<name>``, as in the full corpus."""
    files = sorted(DEMO_MATERIALS_DIR.glob("*.h5"))
    mats = tuple(Material(p.stem, "merl", str(p)) for p in files)
    return Corpus("merl-demo", list_corpora()["merl-demo"], mats, test_only=True)


def list_corpora() -> dict[str, str]:
    """Every corpus this machine knows.

    Returns
    -------
    dict of str to str
        Corpus name -> a one-line description; corpora whose data are absent (e.g.
        ``merl`` without ``../shared/data``) are listed as unavailable.
    """
    out = {"mitsuba": f"built-in: {len(mitsuba_catalog())} Mitsuba 3 BSDFs tabulated on the grid",
           "merl-demo": f"built-in: {len(list(DEMO_MATERIALS_DIR.glob('*.h5')))} measured MERL "
                        "materials (Neural-BRDF fits, merl test split), shipped for the demo"}
    data = shared_data_dir()
    for name in ("merl", "rgl"):
        if data and (data / "nbrdf" / name).is_dir():
            n = len(list((data / "nbrdf" / name).glob("*.h5")))
            out[name] = f"{n} Neural-BRDF fits of measured {name.upper()} materials ({data})"
        else:
            out[name] = "unavailable: ../shared/data/nbrdf not found (set SPARSE_BRDF_DATA)"
    return out


def get_corpus(name: str) -> Corpus:
    """A corpus by name or by folder.

    Parameters
    ----------
    name : str
        A name from :func:`list_corpora` (``"mitsuba"``, ``"merl-demo"``, ``"merl"``,
        ``"rgl"``, ...), or the path of a folder of ``.binary`` (MERL/DTU) and ``.h5``
        (Neural-BRDF) files.

    Returns
    -------
    Corpus
        Its materials, with the split by name hash (``Corpus.split("test")``).

    Raises
    ------
    MissingDataError
        For a corpus whose data are not on this machine (``../shared/data``).
    MissingFileError
        (a FileNotFoundError) For a folder without material files.
    UsageError
        For an unknown or empty name.
    """
    if not isinstance(name, str) or not name.strip():
        raise UsageError(f"corpus {name!r}: give mitsuba, merl, rgl or a folder path")
    if name == "mitsuba":
        mats = tuple(Material(n, "mitsuba", f"mitsuba:{n}") for n in sorted(mitsuba_catalog()))
        return Corpus("mitsuba", list_corpora()["mitsuba"], mats)
    if name == "merl-demo":
        return _demo_corpus()
    if name in ("merl", "rgl"):
        data = shared_data_dir()
        if data is None or not (data / "nbrdf" / name).is_dir():
            raise MissingDataError(
                f"corpus {name!r} needs ../shared/data/nbrdf/{name} (or SPARSE_BRDF_DATA); "
                "it is not on this machine"
            )
        return _folder_corpus(name, data / "nbrdf" / name, list_corpora()[name])
    folder = Path(name)
    if folder.is_dir():
        c = _folder_corpus(folder.name, folder, f"folder {folder}")
        if not c.materials:
            raise MissingFileError(f"{folder}: no .binary or .h5 files in this folder")
        return c
    raise UsageError(f"unknown corpus {name!r}: use mitsuba, merl, rgl or a folder path")
