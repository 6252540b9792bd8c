"""The batch encoder: every material of a folder or glob encoded into a folder of
``.sbrdf`` files with a summary (``sparse-brdf encode DIR_OR_GLOB -o OUT_DIR``).

:func:`encode_batch` encodes every material it finds (``.binary`` and ``.h5``; a glob may
also match ``.sbrdf`` files) to ``OUT_DIR/<stem>.sbrdf`` and writes ``summary.csv`` and
``summary.json`` there: per material its status (``encoded``, ``skipped``, ``failed``),
the SNR proxy (the cosine-weighted BRDF-space SNR of the decoded model,
``metrics.cosine_weighted_snr``), file bytes, transform, coefficients and seconds
(loading and encoding apart). It checks its inputs once, before any material is read:
the output folder, the sources, and the request as one
:class:`~sparse_brdf.coding.spec.EncodeSpec` (the ensemble resolved, the options checked).

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

This module sits above ``coding/`` and ``sources/`` (it loads materials and encodes
them) and below the command line (``docs/architecture.md``, "Rules").
"""

from __future__ import annotations

import csv
import glob
import io
import json
import os
import time
from pathlib import Path

from .coding.encode import encode_with
from .coding.ensemble import Ensemble
from .coding.fileformat import load_sbrdf, save_sbrdf
from .coding.spec import EncodeSpec
from .errors import BRDFFileError, EnsembleMismatchError, MissingFileError, OutputError, UsageError
from .fileio import atomic_write
from .metrics import cosine_weighted_snr
from .parallel import Executor, InProcess
from .sources.load import SUFFIXES, load_brdf

#: What a folder contributes to a batch (a glob may also match the other SUFFIXES).
FOLDER_SUFFIXES = (".binary", ".h5")
#: Seconds between rewrites of the summary while a batch runs (it is also written at the end).
SUMMARY_EVERY_S = 5.0
#: The columns of ``summary.csv`` (and the keys of each row of ``summary.json``).
SUMMARY_FIELDS = ("material", "source", "output", "status", "snr_proxy_db", "bytes",
                  "transform", "coefficients", "load_s", "seconds", "error")
SUMMARY_JSON, SUMMARY_CSV = "summary.json", "summary.csv"


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
    """Encode every material of ``pattern`` (a folder or a glob) into ``out_dir``, one
    ``<stem>.sbrdf`` file each, with ``summary.json`` and ``summary.csv``.

    The output folder, the sources and the request (one
    :class:`~sparse_brdf.coding.spec.EncodeSpec`: the ensemble resolved, the options
    checked) are checked once, before any material is read.

    Parameters
    ----------
    pattern : path or str
        A folder (its ``.binary`` and ``.h5`` files) or a glob pattern.
    out_dir : path
        The output folder (made if absent; refused if it is a file, or if its summary
        records other options or another ensemble).
    ensemble : Ensemble, path or id, optional
        Resolved once (default: the shipped one).
    options : dict, optional
        Keyword arguments of :func:`~sparse_brdf.coding.encode.encode` (``n_coeffs``,
        ``transform``, ``selector``, ...), and ``symmetrize`` as
        :func:`~sparse_brdf.sources.load.load_brdf` takes it.
    ex : Executor, optional
        Where the work runs (default: in this process).
    progress : bool
        Show a progress bar.

    Returns
    -------
    dict
        The summary (``summary.json``'s content): ``rows`` in input order (per material
        its status, SNR proxy in dB, bytes, transform, coefficients, seconds), the counts
        ``encoded``, ``skipped``, ``failed``, the ensemble id, options and grid.
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
