"""Named corpora of materials and their deterministic train/test split.

- ``mitsuba``: built into the package, always there: Mitsuba 3 BSDFs (measured-IOR
  rough conductors, rough plastics, principled paints with clearcoat and sheen,
  diffuse; :mod:`sparse_brdf.sources.catalog`), tabulated through ``mi.BSDF.eval``.
- ``merl``, ``rgl``: Neural-BRDF fits of measured MERL and RGL-EPFL materials, found in
  ``../shared/data/nbrdf`` (or ``$SPARSE_BRDF_DATA/nbrdf``) when present.
- ``abc``, ``sgd``: the published analytic fits of the MERL materials (ABC, Löw et al.
  2012; shifted gamma distribution, Bagher et al. 2012; public-domain parameters in
  ``../shared/data/fits``), tabulated from the models' formulas
  (:mod:`sparse_brdf.sources.fits`): materials that no network produced.
- any folder of ``.binary`` (MERL/DTU) or ``.h5`` (Neural-BRDF) files, given by path.

Split: within a corpus, materials are ranked by sha256("<corpus>/<name>") and the first
``round(0.15 * n)`` (at least 1) form the test split; the rest train. The rule depends
only on names, so adding a material never moves another one across the split.

A corpus of other versions of another corpus's materials shares that corpus's split
(``Corpus.split_from``): ``abc`` and ``sgd`` take ``merl``'s, so that their test
materials are exactly ``merl``'s test materials (by sha256("merl/<name>")) and an
ensemble trained on the training splits never saw them in any form. A fit of a material
that ``merl`` lacks goes to the test split: no ensemble trained on it.
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
from .fits import FIT_FILES, FIT_MODELS, fit_names
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

    def load(self, shape: tuple[int, int, int] = MERL_SHAPE,
             symmetrize: bool | None = None) -> BRDF:
        """Tabulate the material (cached on disk, see :func:`~sparse_brdf.load_brdf`).

        Parameters
        ----------
        shape : tuple of int
            The grid (n_h, n_d, n_p); default the MERL grid (90, 90, 180).
        symmetrize : bool, optional
            As :func:`~sparse_brdf.load_brdf` (None: networks symmetrised).

        Returns
        -------
        BRDF
            Its values on that grid, named :attr:`name`.
        """
        brdf = load_brdf(self.source, shape=shape, symmetrize=symmetrize)
        brdf.name = self.name
        return brdf


#: The splits of a corpus (``Corpus.split``; a bench's and the trainer's ``split``).
SPLITS: tuple[str, ...] = ("train", "test", "all")
#: The corpora the trainer reads unless told otherwise (``sparse-brdf train --corpus``).
TRAINING_CORPORA: tuple[str, ...] = ("merl", "rgl", "mitsuba")
#: The corpora known by name (besides folders), as ``sparse-brdf corpus list`` shows them.
NAMED_CORPORA: tuple[str, ...] = ("mitsuba", "merl-demo", "merl", "rgl", *FIT_MODELS)
#: The corpus whose split the analytic fits share (their materials are MERL's).
FITS_SPLIT_FROM = "merl"


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
    split_from : str or None
        The corpus whose split this one shares, for other versions of its materials
        (``"merl"`` for ``abc`` and ``sgd``): a material is in the test split if it is
        in that corpus's test split or absent from that corpus. None: the corpus's own
        name-hash split.
    """

    name: str
    description: str
    materials: tuple[Material, ...]
    test_only: bool = False  # every material is unseen (e.g. the shipped demo materials)
    split_from: str | None = None  # share this corpus's split (same materials, other form)

    def __repr__(self) -> str:
        return (f"Corpus({short(self.name)!r}, {len(self.materials)} materials"
                f"{', test only' if self.test_only else ''}"
                f"{f', split of {self.split_from}' if self.split_from else ''})")

    def split(self, which: str = "all") -> list[Material]:
        """The materials of one split.

        Parameters
        ----------
        which : str
            ``"train"``, ``"test"`` or ``"all"`` (``SPLITS``). The test split is a fixed
            15 % of the names (at least one), chosen by a hash of corpus and name, so it
            does not change when materials are added; a test-only corpus has no
            training split; a corpus with ``split_from`` takes that corpus's test
            materials, and the materials that corpus lacks, as its test split.

        Returns
        -------
        list of Material
            In name order.

        Raises
        ------
        UsageError
            For a split not in ``SPLITS``.
        MissingDataError
            For a ``split_from`` corpus whose data are not on this machine.
        """
        if check_choice("split", which, SPLITS) == "all":
            return list(self.materials)
        if self.test_only:
            return list(self.materials) if which == "test" else []
        names = [m.name for m in self.materials]
        if self.split_from is None:
            test = set(test_names(self.name, names))
        else:
            other = get_corpus(self.split_from)
            test = ({m.name for m in other.split("test")}
                    | (set(names) - {m.name for m in other.materials}))
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
    papers = {"abc": "ABC fits (Löw et al. 2012)", "sgd": "SGD fits (Bagher et al. 2012)"}
    for name in FIT_MODELS:
        try:
            n = len(fit_names(name))
        except MissingDataError:
            out[name] = (f"unavailable: ../shared/data/fits/{FIT_FILES[name]} not found "
                         "(set SPARSE_BRDF_DATA)")
            continue
        out[name] = (f"{n} {papers[name]} of measured MERL materials, tabulated (public "
                     f"domain; {FITS_SPLIT_FROM}'s split)")
    return out


def get_corpus(name: str) -> Corpus:
    """A corpus by name or by folder.

    Parameters
    ----------
    name : str
        A name from :func:`list_corpora` (``"mitsuba"``, ``"merl-demo"``, ``"merl"``,
        ``"rgl"``, ``"abc"``, ``"sgd"``), or the path of a folder of ``.binary``
        (MERL/DTU) and ``.h5`` (Neural-BRDF) files.

    Returns
    -------
    Corpus
        Its materials, with the split by name hash (``Corpus.split("test")``).

    Raises
    ------
    MissingDataError
        For a corpus whose data are not on this machine (``../shared/data``); the
        message names the folder or file.
    MissingFileError
        (a FileNotFoundError) For a folder without material files.
    UsageError
        For an unknown or empty name.
    """
    if not isinstance(name, str) or not name.strip():
        raise UsageError(f"corpus {name!r}: give {', '.join(NAMED_CORPORA)} or a folder path")
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
    if name in FIT_MODELS:
        mats = tuple(Material(n, name, f"{name}:{n}") for n in fit_names(name))
        return Corpus(name, list_corpora()[name], mats, split_from=FITS_SPLIT_FROM)
    folder = Path(name)
    if folder.is_dir():
        c = _folder_corpus(folder.name, folder, f"folder {folder}")
        if not c.materials:
            raise MissingFileError(f"{folder}: no .binary or .h5 files in this folder")
        return c
    raise UsageError(f"unknown corpus {name!r}: use {', '.join(NAMED_CORPORA)} or a folder "
                     "path")
