"""The evaluation harness: models side by side on the same scenes, sampler and seed.

``sparse-brdf bench [CONFIG.toml]`` runs a suite and writes ``results.csv``,
``results.json`` (a versioned schema, :mod:`~sparse_brdf.benchmark.results_file`),
``report.md`` with PNG figures and the self-contained ``report.html`` into the output
folder. Finished
cells (material x model) are kept in ``results.json`` and skipped on a re-run, so an
interrupted bench resumes. Every model is rendered in every scene of the config through
the same sampler and seed as the reference (the full tabulated BRDF), so the Monte Carlo
noise cancels in the difference; each rendering SNR is recorded in both forms
(whole-image, the paper's; object-only, the strict one), beside the noise floor (two
reference renders with different seeds), and HDR-FLIP over the object's pixels with its
error map kept for the reports. Scenes are scene specs (``sphere_light.xml:lightangle=40``,
:func:`~sparse_brdf.evaluation.render.parse_scene_spec`); both plugins sample
cosine-weighted (:data:`~sparse_brdf.evaluation.render.SHARED_PATHS`). Models are specs
(:mod:`~sparse_brdf.compared.specs`), built-in or ``module:Class`` from outside the package,
all following :mod:`~sparse_brdf.compared.protocol`. A scene whose data is absent (the paper's scene
without the Grace Cathedral map) is skipped with a one-line reason. Each model's speed
is its own evaluation rate (evaluations per second, :mod:`sparse_brdf.speed`).

Fairness: a model that learns from a training set (PCA) is trained only on materials
that the bench does not evaluate; a config that leaves none is refused.
"""

from __future__ import annotations

import copy
import glob
import shutil
import sys
import uuid
from dataclasses import asdict
from pathlib import Path

from ..brdf import BRDF
from ..coding.encode import error_curve
from ..coding.ensemble import Ensemble, resolve_ensemble
from ..coding.fileformat import VERSION
from ..coding.spec import ENCODE_OPTIONS
from ..errors import MissingDataError, one_line
from ..evaluation.scenes import check_scene_data, parse_scene_spec
from ..fileio import atomic_write, parse_strict_json, strict_json
from ..parallel import Executor, InProcess
from .bench_config import (
    BenchConfig,
    check_training_set,
    evaluated_materials,
    file_stem,
    learners_training_set,
    make_models,
    material_key,
)
from .cells import CellRunner
from .html_report import write_html_report
from .provenance import cell_provenance, environment_provenance, stale_cells
from .report import failed_cells, write_report
from .results_file import READ_SCHEMAS, SCHEMA, environment
from .stability import run_stability

__all__ = ["Bench", "BenchResults"]


class BenchResults:
    """The results of one bench folder (``results.json``): started fresh, or resumed from
    an earlier run of the same config (its models aside: each cell has its own
    provenance), ensemble, encoder, renderer and machine; saved atomically; the cells
    whose provenance changed dropped with their cached renders.

    Parameters
    ----------
    cfg : BenchConfig
        The bench's config.
    ensemble : Ensemble
        The ensemble the sparse models use (part of the results' provenance).
    work : Path
        The bench's cache of renders and files (emptied when earlier results go).
    """

    def __init__(self, cfg: BenchConfig, ensemble: Ensemble, work: Path):
        self.path = Path(cfg.out) / "results.json"
        self.work = work
        self.data = self._load(cfg, ensemble)

    @staticmethod
    def provenance(ensemble: Ensemble) -> dict:
        """What every result depends on beyond the config: the ensemble the sparse models
        use, the encoder's defaults, the .sbrdf version written (all changed between
        versions), the renderer's versions and the machine (the reference renders)."""
        return {"ensemble": ensemble.id,
                "encoder_defaults": dict(ENCODE_OPTIONS), "sbrdf_version": VERSION,
                "environment": environment_provenance()}

    def _load(self, cfg: BenchConfig, ensemble: Ensemble) -> dict:
        """Earlier results of this config (a resumed run), else a fresh record; results of
        another config (its models aside: each cell has its own provenance), ensemble,
        encoder, renderer or machine are discarded with the renders they cached."""
        p = self.path
        fresh = {"schema": SCHEMA, "run": uuid.uuid4().hex, "config": asdict(cfg),
                 "provenance": self.provenance(ensemble), "cells": {}, "curves": {},
                 "noise_floor": {}, "speed": {}, "speed_spread": {},
                 "skipped_scenes": {}}
        if p.is_file():
            data = parse_strict_json(p.read_text())
            if data.get("schema") in READ_SCHEMAS and _settings(data.get("config")) == \
                    _settings(fresh["config"]) and data.get("provenance") == fresh["provenance"]:
                data["schema"] = SCHEMA  # a version-1 file is rewritten as strict JSON
                data.setdefault("run", fresh["run"])  # a file from before run ids
                data["config"] = fresh["config"]  # its models may have changed
                return data
            if self.work.is_dir():  # cached renders and files of the old results
                shutil.rmtree(self.work)
        return fresh

    def save(self) -> None:
        """Write ``results.json`` (strict JSON), atomically."""
        with atomic_write(self.path, "w") as f:
            f.write(strict_json(self.data))

    def drop_stale_cells(self, provenance: dict[str, dict], n_cells: int) -> None:
        """Drop the recorded cells whose provenance changed (:func:`stale_cells`), with
        their cached renders and their models' speeds; say on stdout how many cells are
        kept, when there were any. ``provenance``: each model's current cell provenance
        (by model name)."""
        cells = self.data["cells"]
        if not cells:
            return
        stale, kept = stale_cells(cells, provenance)
        changed = {cells[key]["model"] for key in stale} & set(provenance)
        n_changed = sum(cells[key]["model"] in changed for key in stale)
        for key in stale:
            stem = f"{file_stem(key.split('|')[0])}__{cells.pop(key)['model']}"
            for scene in self.work.glob("*/"):
                for suffix in (".exr", ".json", ".flip.npy"):
                    (scene / f"{stem}{suffix}").unlink(missing_ok=True)  # cached outputs
                for f in scene.glob(f"{glob.escape(stem)}@s*"):  # of the other seeds
                    f.unlink(missing_ok=True)
        for name in list(self.data["speed"]):
            if name in changed or name not in provenance:
                del self.data["speed"][name]
                self.data.get("speed_spread", {}).pop(name, None)
        print(f"bench: kept {kept} of {n_cells} cells, {n_cells - kept} to compute "
              f"({n_changed} recorded with another model source, options or environment)")


class Bench:
    """Runs a :class:`BenchConfig`: the materials, the models (trained where they learn)
    and the order of the work, on an executor; results accumulate in ``self.results``
    (kept by :class:`BenchResults`), the cells are computed by a
    :class:`~sparse_brdf.benchmark.cells.CellRunner` (``self.cells``), and the reports are
    written at the end (``report``, ``html_report``). Decoded tables (``work/*.binary``,
    35 MB each) are deleted once used unless ``keep_work``."""

    def __init__(self, cfg: BenchConfig, progress: bool = True, keep_work: bool = False):
        self.cfg, self.keep_work = cfg, keep_work
        self.out = Path(cfg.out)
        self.work = self.out / "work"
        self.progress = progress
        self.ensemble = resolve_ensemble(cfg.ensemble)  # read once: provenance and models
        self.store: BenchResults | None = BenchResults(cfg, self.ensemble, self.work)
        self.results = self.store.data
        self.cells = CellRunner(cfg, self.work, keep_work, self.results)
        self._cell_provenance: dict[str, dict] = {}  # model name -> its cells' (run())
        self._loaded: tuple = (None, None)  # the last material loaded (key, BRDF)

    def _save(self) -> None:
        self.store.save()

    def materials(self) -> list:
        """The materials the bench evaluates (:func:`evaluated_materials`)."""
        return evaluated_materials(self.cfg)

    def training_materials(self, evaluated) -> list:
        """Training materials for learned models (:func:`~.bench_config.learners_training_set`)."""
        return learners_training_set(self.cfg, evaluated)

    def _resolve_scenes(self) -> None:
        """The config's scenes that can run here; the others are skipped with a reason."""
        for name in self.cfg.scenes:
            spec = parse_scene_spec(name)
            try:
                check_scene_data(spec.path, spec.params)
            except MissingDataError as exc:
                self.results["skipped_scenes"][spec.key] = str(exc)
                print(f"bench: skipping scene {spec.key}: {exc}", file=sys.stderr)
                continue
            self.cells.scenes[spec.key] = spec

    # ------------------------------------------------------------------ running
    def run(self, ex: Executor | None = None) -> dict:
        """Run what is not done yet; ``ex``: where the materials' reference renders and
        the cells run (``parallel.executor``; default: here, one after another). Results
        are saved as each arrives, and are the same wherever they ran (same seeds)."""
        self.out.mkdir(parents=True, exist_ok=True)
        self.work.mkdir(parents=True, exist_ok=True)
        if self.cfg.render:
            self._resolve_scenes()
        ens = self.ensemble
        models = make_models(self.cfg.models, ens if self.cfg.ensemble else None)
        self._cell_provenance = {m.name: cell_provenance(spec)
                                 for spec, m in zip(self.cfg.models, models, strict=True)}
        mats = self.materials()
        self.store.drop_stale_cells(self._cell_provenance, len(models) * len(mats))
        self._train(models, mats)
        self._run_cells(ex or InProcess(), ens, models, mats)
        for table in [] if self.keep_work else self.work.glob("*__reference.binary"):
            table.unlink(missing_ok=True)  # written again if a later run needs it
        finished = {c["model"] for c in self.results["cells"].values()
                    if c.get("status") == "finished"}
        # a model none of whose cells finished has no speed: it would rank what failed
        missing = [mod for mod in models
                   if mod.name not in self.results["speed"] and mod.name in finished]
        if self.cfg.speed and missing and mats:  # e.g. measurements deleted to redo them
            brdf = mats[0].load()
            for mod in missing:
                try:
                    self.cells.speed(mod, mod.compress(brdf))
                except Exception as exc:  # noqa: BLE001 - as in a cell: never stops the run
                    print(f"bench: no speed for {mod.name}: {type(exc).__name__}: "
                          f"{one_line(exc)}", file=sys.stderr)
                    continue
                self._save()
        if self.cfg.stability and "stability" not in self.results and mats:
            smodels = make_models(self.cfg.stability_models,
                                  ens if self.cfg.ensemble else None)
            self._train(smodels, mats)
            self.results["stability"] = {
                "material": material_key(mats[0]),
                "rows": run_stability(mats[0].load(), smodels, self.work / "stability")}
            self._save()
        self.results["environment"] = environment()  # where the last run ran
        self._save()
        write_report(self.results, self.out)
        write_html_report(self.results, self.out)
        failed = failed_cells(self.results)
        if failed:
            first = failed[0]
            print(f"bench: {len(failed)} of {len(self.results['cells'])} cells failed, listed "
                  f"with their errors in {self.out / 'report.md'} (first: {first['model']} on "
                  f"{first['material']}: {one_line(first['error'])})", file=sys.stderr)
        return self.results

    def _run_cells(self, ex: Executor, ens, models, mats) -> None:
        """Each material's error curve and reference renders, then every cell, on ``ex``;
        each result is saved as it arrives (so an interrupted bench resumes)."""
        from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `sparse-brdf --help`

        todo_mats = [m for m in mats if material_key(m) not in self.results["curves"] or any(
            material_key(m) not in self.results["noise_floor"].get(s, {})
            for s in self.cells.scenes)]
        cells = self.results["cells"]  # failed cells run again: the model may be mended
        todo = [(m, mod) for m in mats for mod in models
                if cells.get(f"{material_key(m)}|{mod.name}", {}).get("status") != "finished"]
        # closed on an error too, so that the error line starts a line of its own
        with tqdm(total=len(todo) + len(todo_mats), desc="bench",
                  disable=not self.progress) as bar:
            bench = ex.scatter(self._for_workers(ex))
            for i, (curve, floors) in ex.as_completed(_material_task, todo_mats, bench,
                                                      ex.scatter(ens)):
                key = material_key(todo_mats[i])
                self.results["curves"][key] = curve
                for scene, floor in floors.items():
                    self.results["noise_floor"].setdefault(scene, {})[key] = floor
                self._save()
                bar.update(1)
            shipped = {name: ex.scatter(mod) for name, mod in {m.name: m for _, m in todo}.items()}
            for i, row in ex.as_completed(_cell_task, [(m, shipped[mod.name]) for m, mod in todo],
                                          bench):
                m, mod = todo[i]
                row["provenance"] = self._cell_provenance[mod.name]
                self.results["cells"][f"{material_key(m)}|{mod.name}"] = row
                self._save()
                bar.update(1)

    def _for_workers(self, ex: Executor) -> Bench:
        """This bench as a worker needs it: itself in-process; otherwise a copy without the
        results (they stay here) that leaves the speed measurements to this process (the
        ``missing`` pass of :meth:`run`), its scenes' object masks computed beforehand."""
        if not ex.distributed:
            return self
        for scene in self.cells.scenes:
            self.cells.mask(scene)
        lite, lite_cells = copy.copy(self), copy.copy(self.cells)
        lite.results = lite_cells.results = {"speed": {}}
        lite.store, lite.cells, lite.progress = None, lite_cells, False
        lite_cells.cell_speed = False
        return lite

    def _load(self, m) -> BRDF:
        """Material ``m``'s BRDF, loaded once for consecutive cells of one material."""
        if self._loaded[0] != material_key(m):
            self._loaded = (material_key(m), m.load())
        return self._loaded[1]

    def _train(self, models, evaluated) -> None:
        needs = [m for m in models if m.learns]
        if not needs:
            return
        train = self.training_materials(evaluated)
        overlap = {material_key(m) for m in train} & {material_key(m) for m in evaluated}
        assert not overlap, f"training and evaluated materials overlap: {sorted(overlap)}"
        check_training_set(self.cfg, needs, train)
        brdfs = [m.load() for m in train]
        for m in needs:
            m.fit(brdfs)
            m.trained_on = [material_key(t) for t in train]

    def _curve(self, brdf, ens) -> dict:
        """Error against coefficients and the transform choices (Fig. 2, Table 2)."""
        return error_curve(brdf, ens, self.cfg.curve_coeffs)


def _settings(config) -> dict | None:
    """A results file's config without its models (each cell has its own provenance)."""
    return {k: v for k, v in config.items() if k != "models"} if isinstance(config, dict) \
        else None


def _material_task(m, bench: Bench, ens) -> tuple[dict, dict]:
    """A material's error curve and noise floors (reference renders), for any executor."""
    brdf = bench._load(m)
    return bench._curve(brdf, ens), bench.cells.references(material_key(m), brdf)


def _cell_task(item: tuple, bench: Bench) -> dict:
    """One cell (material, model), for any executor."""
    m, model = item
    return bench.cells.cell(material_key(m), bench._load(m), model)
