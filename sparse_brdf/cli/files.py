"""Encoding files: one material to a ``.sbrdf`` file, or a folder or glob to a folder.

``sparse-brdf encode SOURCE -o OUT.sbrdf`` (:func:`encode_file`) loads one material,
encodes it (at a coefficient count, or to a byte budget) and writes its file atomically;
it checks its inputs first (the output: a ``.sbrdf`` name, neither a folder nor one of
the inputs, writable; the request as an :class:`~sparse_brdf.coding.spec.EncodeSpec`:
the ensemble resolved once, the counts and options checked once).

``sparse-brdf encode DIR_OR_GLOB -o OUT_DIR`` (:func:`encode_batch`) encodes every
material it finds (``.binary`` and ``.h5``; a glob may also match ``.sbrdf`` files) to
``OUT_DIR/<stem>.sbrdf`` and writes ``summary.csv`` and ``summary.json`` there: per
material its status (``encoded``, ``skipped``, ``failed``), the SNR proxy (the
cosine-weighted BRDF-space SNR of the decoded model, ``metrics.cosine_weighted_snr``),
file bytes, transform, coefficients and seconds (loading and encoding apart).

Resumable: an output that exists, reads as a ``.sbrdf`` file (checksum) and names the
run's ensemble is kept and reported as ``skipped`` (with the figures of the run that
wrote it, when its summary has them). The summary is written atomically at the start
(recording the options), every ``SUMMARY_EVERY_S`` seconds and at the end; an
interrupted run keeps its finished outputs, which the next run finds and skips. A folder
whose summary records other encoder options is refused rather than mixed.

Failures: a material that cannot be loaded or encoded is reported in the summary with
its error, and the other materials go on; the command's exit status is then 1.

Where the work runs (``parallel.executor``): each material is one piece of work, the
ensemble is sent once to each worker, the workers read the materials themselves (so
with ``--scheduler`` the inputs must be on a file system the workers see) and return the
coefficients; this process writes every output. Encoding is deterministic, so the files
are the same bytes wherever they were encoded (``tests/test_parallel.py``).
"""

from __future__ import annotations

import csv
import glob
import io
import json
import os
import time
from pathlib import Path

import numpy as np

from ..acquisition.files import read_samples, write_samples
from ..acquisition.measurements import Samples
from ..acquisition.planning import plan
from ..acquisition.recovery import encode_samples
from ..coding.budget import encode_to_bytes_with
from ..coding.coefficients import SparseBRDF
from ..coding.encode import encode_with
from ..coding.ensemble import Ensemble
from ..coding.fileformat import SBRDF_FILE, load_sbrdf, save_sbrdf
from ..coding.spec import DEFAULT_N_COEFFS, EncodeSpec
from ..errors import BRDFFileError, EnsembleMismatchError, MissingFileError, OutputError, UsageError
from ..fileio import atomic_write, check_new_output, check_output
from ..metrics import cosine_weighted_snr
from ..parallel import Executor, InProcess
from ..params import Interval, check
from ..sources.load import SUFFIXES, load_brdf

#: What a folder contributes to a batch (a glob may also match the other SUFFIXES).
FOLDER_SUFFIXES = (".binary", ".h5")
#: Seconds between rewrites of the summary while a batch runs (it is also written at the end).
SUMMARY_EVERY_S = 5.0
#: The columns of ``summary.csv`` (and the keys of each row of ``summary.json``).
SUMMARY_FIELDS = ("material", "source", "output", "status", "snr_proxy_db", "bytes",
                  "transform", "coefficients", "load_s", "seconds", "error")
SUMMARY_JSON, SUMMARY_CSV = "summary.json", "summary.csv"


def encode_file(source: str | os.PathLike, output: str | os.PathLike,
                ensemble: Ensemble | str | os.PathLike | None = None,
                n_coeffs: int = DEFAULT_N_COEFFS, n_bytes: int | None = None,
                symmetrize: bool | None = None, **options) -> tuple[Path, SparseBRDF]:
    """Encode one material ``source`` (any BRDF source, ``sources.load``) into the
    ``.sbrdf`` file ``output`` (written atomically).

    Parameters
    ----------
    source : path or ``mitsuba:<name>``
        The material.
    output : path
        The ``.sbrdf`` file; refused if it is not named ``.sbrdf``, is a folder, is one of
        the inputs or cannot be written.
    ensemble : Ensemble, path or id, optional
        Resolved once (:meth:`~sparse_brdf.coding.spec.EncodeSpec.build`; default: the
        shipped one).
    n_coeffs : int
        Coefficients per channel, at most (capped at the ensemble's grid).
    n_bytes : int, optional
        A byte budget for the whole file (``coding.budget.encode_to_bytes``) instead of
        ``n_coeffs``.
    symmetrize : bool, optional
        As :func:`~sparse_brdf.sources.load.load_brdf` (None: a network is symmetrised).
    **options
        The other keyword arguments of :func:`~sparse_brdf.coding.encode.encode`
        (``max_error``, ``transform``, ``selector``, ...).

    Returns
    -------
    (Path, SparseBRDF)
        The file written and the model it holds (with the encoder's ``stats``).
    """
    out = check_new_output(output, *SBRDF_FILE, [source, None if isinstance(
        ensemble, Ensemble) else ensemble])
    spec = EncodeSpec.build(ensemble, n_coeffs, n_bytes, **options)
    brdf = load_brdf(source, symmetrize=symmetrize)
    model = (encode_to_bytes_with(brdf, spec) if spec.n_bytes is not None
             else encode_with(brdf, spec))
    return save_sbrdf(out, model), model


def is_batch(source: str | os.PathLike) -> bool:
    """Whether an encode source names many materials: a folder, or a glob pattern that is
    not itself a file."""
    s = os.fspath(source)
    return Path(s).is_dir() or (glob.has_magic(s) and not Path(s).exists())


def batch_sources(pattern: str | os.PathLike) -> list[Path]:
    """The material files of a folder (``FOLDER_SUFFIXES``) or a glob, sorted; raises
    :class:`~sparse_brdf.errors.MissingFileError` if there are none, UsageError if two
    share an output name."""
    s = os.fspath(pattern)
    if Path(s).is_dir():
        files = [p for p in Path(s).iterdir() if p.suffix.lower() in FOLDER_SUFFIXES]
    else:
        files = [Path(p) for p in glob.glob(s) if Path(p).suffix.lower() in SUFFIXES]
    files = sorted(p for p in files if p.is_file())
    if not files:
        raise MissingFileError(f"{s}: no materials ({', '.join(SUFFIXES)} files) found")
    by_stem: dict[str, list[str]] = {}
    for p in files:
        by_stem.setdefault(p.stem, []).append(str(p))
    clash = {k: v for k, v in by_stem.items() if len(v) > 1}
    if clash:
        first = next(iter(clash.values()))
        raise UsageError(f"{s}: {len(clash)} output names are shared by several materials "
                         f"(e.g. {' and '.join(first)}); encode them into separate folders")
    return files


def encode_material(source: str, spec: EncodeSpec, symmetrize: bool | None = None) -> dict:
    """Load and encode one material by a resolved request; its summary row, with the model
    under ``"model"`` (runs on a worker: every error is caught and reported, never
    raised)."""
    row: dict = {"source": source}
    try:
        t0 = time.perf_counter()
        brdf = load_brdf(source, symmetrize=symmetrize)
        t1 = time.perf_counter()
        model = encode_with(brdf, spec)
        t2 = time.perf_counter()
        rec = model.decode(spec.ensemble, valid=brdf.valid).values
        row.update(status="encoded", model=model, transform=model.transform,
                   coefficients=int(model.n_coeffs.sum()), load_s=t1 - t0, seconds=t2 - t1,
                   snr_proxy_db=cosine_weighted_snr(brdf.values, rec, brdf.valid))
    except Exception as exc:  # noqa: BLE001 - one material's failure never stops the batch
        row.update(status="failed", error=f"{type(exc).__name__}: {exc}")
    return row


def _finished(path: Path, ens: Ensemble) -> bool:
    """``path`` holds a complete ``.sbrdf`` file encoded with ``ens``."""
    if not path.is_file():
        return False
    try:
        load_sbrdf(path, ens)
    except (BRDFFileError, EnsembleMismatchError, OSError, ValueError):
        return False
    return True


def _run_key(ens: Ensemble, options: dict) -> dict:
    return {"ensemble": ens.id, "options": options}


def _previous(out: Path, key: dict) -> dict[str, dict]:
    """Rows of an earlier run's summary in ``out`` by material; refuse other options."""
    path = out / SUMMARY_JSON
    if not path.is_file():
        return {}
    try:
        old = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    if {k: old.get(k) for k in key} != key:
        raise UsageError(f"{out}: holds a batch encoded with other options or another "
                         f"ensemble ({path}); use another output folder or empty it")
    return {r["material"]: r for r in old.get("rows", [])}


def _skipped_row(src: Path, path: Path, ens: Ensemble, before: dict | None) -> dict:
    """The row of an output kept from an earlier run."""
    if before is not None and before.get("status") in ("encoded", "skipped"):
        return {**before, "source": str(src), "output": str(path), "status": "skipped"}
    model = load_sbrdf(path, ens)
    return {"source": str(src), "output": str(path), "status": "skipped",
            "bytes": path.stat().st_size, "transform": model.transform,
            "coefficients": int(model.n_coeffs.sum())}


def write_summary(out: Path, rows: list[dict], meta: dict) -> None:
    """``summary.json`` (``meta`` and the rows) and ``summary.csv``, each atomically."""
    clean = [{k: r.get(k) for k in SUMMARY_FIELDS} for r in rows if r is not None]
    counts = {s: sum(r["status"] == s for r in clean) for s in ("encoded", "skipped", "failed")}
    with atomic_write(out / SUMMARY_JSON, "w") as f:
        json.dump({**meta, **counts, "materials": len(clean), "rows": clean}, f, indent=1)
    buf = io.StringIO()
    w = csv.DictWriter(buf, SUMMARY_FIELDS, lineterminator="\n")
    w.writeheader()
    w.writerows(clean)
    with atomic_write(out / SUMMARY_CSV, "w") as f:
        f.write(buf.getvalue())


def encode_batch(pattern: str | os.PathLike, out_dir: str | os.PathLike,
                 ensemble: Ensemble | str | None = None, options: dict | None = None,
                 ex: Executor | None = None, progress: bool = True) -> dict:
    """Encode every material of ``pattern`` (a folder or a glob) into ``out_dir``.

    ``options``: keyword arguments of :func:`~sparse_brdf.coding.encode.encode`
    (``n_coeffs``, ``transform``, ``selector``, ...), and ``symmetrize`` as
    :func:`~sparse_brdf.sources.load.load_brdf` takes it. ``ex``: where the work runs
    (default in-process). Returns the summary (``summary.json``'s content): ``rows`` in
    input order, and the counts ``encoded``, ``skipped``, ``failed``. The output folder,
    the sources and the request (:class:`~sparse_brdf.coding.spec.EncodeSpec`: the
    ensemble resolved, the options checked) are checked once, before any material is read.
    """
    from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `sparse-brdf --help`

    t0 = time.perf_counter()
    out = Path(out_dir)
    if out.is_file():
        raise OutputError(f"-o {out_dir}: a batch writes a folder (one .sbrdf per material "
                          "and its summary), not a file")
    ex = ex or InProcess()
    files = batch_sources(pattern)
    options = dict(options or {})
    symmetrize = options.pop("symmetrize", None)
    spec = EncodeSpec.build(ensemble, **options)
    ens = spec.ensemble
    if options.get("n_coeffs") is not None:
        options["n_coeffs"] = spec.n_coeffs
    if symmetrize is not None:
        options["symmetrize"] = symmetrize
    out.mkdir(parents=True, exist_ok=True)
    key = _run_key(ens, options)
    before = _previous(out, key)
    rows: list[dict | None] = [None] * len(files)
    todo = []
    for i, src in enumerate(files):
        path = out / f"{src.stem}.sbrdf"
        if _finished(path, ens):
            rows[i] = {"material": src.stem, **_skipped_row(src, path, ens, before.get(src.stem))}
        else:
            todo.append(i)
    meta = {**key, "pattern": os.fspath(pattern), "where": ex.describe(),
            "grid": list(ens.shape)}
    handle = ex.scatter(spec)
    write_summary(out, rows, {**meta, "seconds": 0.0})
    bar = tqdm(total=len(todo), desc="encode", unit="material", disable=not progress)
    written = time.perf_counter()
    for j, row in ex.as_completed(encode_material, [str(files[i]) for i in todo], handle,
                                  symmetrize):
        i = todo[j]
        path = out / f"{files[i].stem}.sbrdf"
        model = row.pop("model", None)
        if model is not None:
            save_sbrdf(path, model)
            row.update(output=str(path), bytes=path.stat().st_size)
        rows[i] = {"material": files[i].stem, **row}
        if time.perf_counter() - written > SUMMARY_EVERY_S:
            write_summary(out, rows, {**meta, "seconds": time.perf_counter() - t0})
            written = time.perf_counter()
        bar.set_postfix(failed=sum(r is not None and r["status"] == "failed" for r in rows))
        bar.update(1)
    bar.close()
    ex.release([handle])
    write_summary(out, rows, {**meta, "seconds": time.perf_counter() - t0})
    return json.loads((out / SUMMARY_JSON).read_text())


#: Direction pairs a plan may hold (a CSV of 2^22 rows is about 0.7 GB).
PLAN_PAIRS = Interval(int, 1, 1 << 22)


def samples_constant(samples: Samples) -> bool:
    """Whether every sample has the same RGB value (all zeros, a plan not filled in, or a
    value copied into every row; also a perfectly Lambertian material)."""
    return bool(np.all(samples.rgb == samples.rgb[:1]))


def encode_samples_file(source: str | os.PathLike | Samples, output: str | os.PathLike,
                        ensemble: Ensemble | str | os.PathLike | None = None,
                        n_coeffs: int = DEFAULT_N_COEFFS, n_bytes: int | None = None,
                        seed: int = 0, prior: str = "default") -> tuple[Path, SparseBRDF]:
    """Encode a samples file (``acquisition.files.read_samples``: CSV or ``.npz``) into the
    ``.sbrdf`` file ``output`` (written atomically), by
    :func:`~sparse_brdf.acquisition.defaults.encode_samples`.

    Parameters
    ----------
    source : path or Samples
        The samples file, or samples it was read into (``read_samples``).
    output : path
        The ``.sbrdf`` file; refused if it is not named ``.sbrdf``, is a folder, is one of
        the inputs or cannot be written.
    ensemble : Ensemble, path or id, optional
        Resolved once, by ``encode_samples`` (default: the shipped one).
    n_coeffs : int
        Coefficients per channel, at most (a joint budget of 3 ``n_coeffs``).
    n_bytes : int, optional
        A byte budget for the whole file instead.
    seed : int
        Seed of the cross-validation folds.
    prior : str
        ``"default"`` (the training split's atom prior) or ``"none"`` (every atom of
        every dictionary, no prior).

    Returns
    -------
    (Path, SparseBRDF)
        The file written and the model it holds (with its ``stats``).
    """
    given = isinstance(source, Samples)
    out = check_new_output(output, *SBRDF_FILE, [source.source if given else source,
                                                 None if isinstance(ensemble, Ensemble)
                                                 else ensemble])
    samples = source if given else read_samples(source)
    check_measured(samples)
    # encode_samples resolves the ensemble, checks the counts and resolves the prior, once
    model = encode_samples(samples, ensemble, n_coeffs, n_bytes, seed=seed, prior=prior)
    return save_sbrdf(out, model), model


def check_measured(samples: Samples) -> None:
    """:class:`~sparse_brdf.errors.UsageError` when every sample value is 0 (a plan whose
    values were not filled in): nothing to encode."""
    if not np.any(samples.rgb):
        raise UsageError(f"{samples.source or samples.name}: every sample value is 0: nothing "
                         "to encode (fill in the measured r,g,b of the plan)")


def plan_samples_file(output: str | os.PathLike, n: int, placement: str = "stratified",
                      seed: int = 0) -> Path:
    """Write the direction pairs to measure (``acquisition.planning.plan``) as a CSV samples file
    whose values are 0, to be replaced by the measurements.

    Parameters
    ----------
    output : path
        The CSV file (written atomically).
    n : int
        Direction pairs.
    placement : str
        ``"uniform"``, ``"stratified"`` or ``"bins"``.
    seed : int
        The same seed gives the same pairs.

    Returns
    -------
    Path
        The file written.
    """
    out = check_output(output, [])
    n = check("n", n, PLAN_PAIRS)
    wi, wo = plan(n, placement, seed)
    return write_samples(out, Samples(wi, wo, np.zeros((n if placement != "bins" else
                                                          wi.shape[0], 3)), name=out.stem))
