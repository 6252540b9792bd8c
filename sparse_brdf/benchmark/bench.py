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
import json
import math
import shutil
import sys
import time
import uuid
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..coding.encode import error_curve
from ..coding.ensemble import resolve_ensemble
from ..coding.fileformat import VERSION, save_sbrdf
from ..coding.spec import ENCODE_OPTIONS
from ..compared.compact import Compact
from ..compared.protocol import ComparedModel, check_compressed, table_of
from ..errors import (
    MissingDataError,
    one_line,
)
from ..evaluation.images import read_exr, write_exr
from ..evaluation.render import SHARED_PATHS, noise_floor_snr, object_mask, render_scene
from ..evaluation.scenes import SceneSpec, check_scene_data, parse_scene_spec
from ..fileio import atomic_write, parse_strict_json, strict_json
from ..metrics import cosine_weighted_snr, gamma_mse, hdr_flip, rae, snr_forms
from ..parallel import Executor, InProcess
from ..sources.merl import write_merl
from .bench_config import (
    BenchConfig,
    check_training_set,
    evaluated_materials,
    file_stem,
    learners_training_set,
    make_models,
    material_key,
    render_seeds,
)
from .html_report import write_html_report
from .provenance import cell_provenance, environment_provenance, stale_cells
from .report import failed_cells, write_report
from .results_file import READ_SCHEMAS, SCHEMA, environment
from .speed import measure_speed
from .stability import run_stability

__all__ = ["Bench", "seed_mean"]

class Bench:
    """Runs a :class:`BenchConfig`; results accumulate in ``self.results``. Decoded tables
    (``work/*.binary``, 35 MB each) are deleted once used unless ``keep_work``."""

    def __init__(self, cfg: BenchConfig, progress: bool = True, keep_work: bool = False):
        self.cfg, self.keep_work = cfg, keep_work
        self.out = Path(cfg.out)
        self.work = self.out / "work"
        self.progress = progress
        self.ensemble = resolve_ensemble(cfg.ensemble)  # read once: provenance and models
        self.results = self._load_results()
        self.scenes: dict[str, SceneSpec] = {}  # scene key -> spec, the scenes that can run
        self._masks: dict[str, np.ndarray] = {}
        self.cell_speed = True  # measure each model's speed in its first cell
        self._cell_provenance: dict[str, dict] = {}  # model name -> its cells' (run())
        self._loaded: tuple = (None, None)  # the last material loaded (key, BRDF)

    # ------------------------------------------------------------------ bookkeeping
    def _provenance(self) -> dict:
        """What every result depends on beyond the config: the ensemble the sparse models
        use, the encoder's defaults, the .sbrdf version written (all changed between
        versions), the renderer's versions and the machine (the reference renders)."""
        return {"ensemble": self.ensemble.id,
                "encoder_defaults": dict(ENCODE_OPTIONS), "sbrdf_version": VERSION,
                "environment": environment_provenance()}

    def _load_results(self) -> dict:
        """Earlier results of this config (a resumed run), else a fresh record; results of
        another config (its models aside: each cell has its own provenance), ensemble,
        encoder, renderer or machine are discarded with the renders they cached."""
        p = self.out / "results.json"
        fresh = {"schema": SCHEMA, "run": uuid.uuid4().hex, "config": asdict(self.cfg),
                 "provenance": self._provenance(), "cells": {}, "curves": {},
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

    def _save(self) -> None:
        with atomic_write(self.out / "results.json", "w") as f:
            f.write(strict_json(self.results))

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
            self.scenes[spec.key] = spec

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
        self._drop_stale_cells(len(models) * len(mats))
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
                    self._speed(mod, mod.compress(brdf))
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

    def _drop_stale_cells(self, n_cells: int) -> None:
        """Drop the recorded cells whose provenance changed (:func:`stale_cells`), with
        their cached renders and their models' speeds; say on stdout how many cells are
        kept, when there were any."""
        cells = self.results["cells"]
        if not cells:
            return
        stale, kept = stale_cells(cells, self._cell_provenance)
        changed = {cells[key]["model"] for key in stale} & set(self._cell_provenance)
        n_changed = sum(cells[key]["model"] in changed for key in stale)
        for key in stale:
            stem = f"{file_stem(key.split('|')[0])}__{cells.pop(key)['model']}"
            for scene in self.work.glob("*/"):
                for suffix in (".exr", ".json", ".flip.npy"):
                    (scene / f"{stem}{suffix}").unlink(missing_ok=True)  # cached outputs
                for f in scene.glob(f"{glob.escape(stem)}@s*"):  # of the other seeds
                    f.unlink(missing_ok=True)
        for name in list(self.results["speed"]):
            if name in changed or name not in self._cell_provenance:
                del self.results["speed"][name]
                self.results.get("speed_spread", {}).pop(name, None)
        print(f"bench: kept {kept} of {n_cells} cells, {n_cells - kept} to compute "
              f"({n_changed} recorded with another model source, options or environment)")

    def _run_cells(self, ex: Executor, ens, models, mats) -> None:
        """Each material's error curve and reference renders, then every cell, on ``ex``;
        each result is saved as it arrives (so an interrupted bench resumes)."""
        from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `sparse-brdf --help`

        todo_mats = [m for m in mats if material_key(m) not in self.results["curves"] or any(
            material_key(m) not in self.results["noise_floor"].get(s, {}) for s in self.scenes)]
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
        for scene in self.scenes:
            self._mask(scene)
        lite = copy.copy(self)
        lite.results, lite.progress, lite.cell_speed = {"speed": {}}, False, False
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

    # ------------------------------------------------------------------ rendering
    def _mask(self, scene: str) -> np.ndarray:
        """The object pixels of ``scene`` at the bench's resolution (cached on disk)."""
        if scene not in self._masks:
            path = self.work / scene / "object_mask.npy"
            if path.is_file():
                mask = np.load(path)
            else:
                spec = self.scenes[scene]
                mask = object_mask(spec.path, res=self.cfg.res, params=spec.params,
                                   materials=["material"])
                path.parent.mkdir(parents=True, exist_ok=True)
                with atomic_write(path, "wb") as f:
                    np.save(f, mask)
            self._masks[scene] = mask
        return self._masks[scene]

    def _render(self, scene: str, key: str, filename: str, seed: int,
                tag: str) -> tuple[np.ndarray, float]:
        exr = self.work / scene / f"{file_stem(key)}__{tag}.exr"
        if exr.is_file():
            meta = json.loads(exr.with_suffix(".json").read_text())
            return read_exr(exr), meta["seconds"]
        t0 = time.perf_counter()
        # coefficient files decode with the bench's ensemble file (a shipped one given by
        # id is found from the file itself)
        ens = ({"ensemble": str(Path(self.cfg.ensemble).resolve())}
               if self.cfg.ensemble and filename.endswith(".sbrdf")
               and Path(self.cfg.ensemble).exists() else None)
        spec = self.scenes[scene]
        img = render_scene(spec.path, {"material": filename}, spp=self.cfg.spp,
                           seed=seed, res=self.cfg.res, params=spec.params,
                           sparse_options=ens, sampling=SHARED_PATHS)
        seconds = time.perf_counter() - t0
        write_exr(exr, img)
        with atomic_write(exr.with_suffix(".json"), "w") as f:
            json.dump({"seconds": seconds}, f)
        return img, seconds

    def _scene_figures(self, scene: str, key: str, model: str, ref_file: str,
                       path: str) -> dict:
        """A model's figures in ``scene``: both SNR forms, HDR-FLIP and the render's
        seconds, rendered at each of the bench's seeds (:func:`render_seeds`) beside the
        reference at the same seed; with several seeds, their mean and standard error."""
        per = []
        for i, seed in enumerate(render_seeds(self.cfg)):
            tag = "" if i == 0 else f"@s{seed}"  # the first seed's files keep their names
            ref, _ = self._render(scene, key, ref_file, seed, f"reference{tag}")
            img, secs = self._render(scene, key, path, seed, f"{model}{tag}")
            per.append({**snr_forms(ref, img, self._mask(scene)).as_dict(),
                        "flip": self._flip(scene, key, model, ref, img, keep=i == 0),
                        "render_s": secs})
        return seed_mean(per)

    def _flip(self, scene: str, key: str, model: str, ref: np.ndarray,
              img: np.ndarray, keep: bool = True) -> float | None:
        """HDR-FLIP of a model's render over the object's pixels; its error map is kept
        (``keep``) beside the render (``work/SCENE/MATERIAL__MODEL.flip.npy``, float16)
        for the reports. None where FLIP is undefined (a black reference)."""
        try:
            res = hdr_flip(ref, img, self._mask(scene))
        except ValueError as exc:
            print(f"bench: no HDR-FLIP for {key} / {model} in {scene}: {exc}", file=sys.stderr)
            return None
        if not keep:
            return res.mean
        path = self.work / scene / f"{file_stem(key)}__{model}.flip.npy"
        with atomic_write(path, "wb") as f:
            np.save(f, res.map.astype(np.float16))
        return res.mean

    def _reference_file(self, key: str, brdf) -> str:
        ref_file = self.work / f"{file_stem(key)}__reference.binary"
        if not ref_file.is_file():
            write_merl(ref_file, brdf)
        return str(ref_file)

    def _references(self, key: str, brdf) -> dict:
        """Reference renders of every scene; the noise floor of each (both SNR forms)."""
        floors: dict = {}
        if not self.cfg.render:
            return floors
        ref_file = self._reference_file(key, brdf)
        for scene in self.scenes:
            ref, _ = self._render(scene, key, ref_file, self.cfg.seed, "reference")
            alt, _ = self._render(scene, key, ref_file, self.cfg.noise_seed, "reference-seed2")
            floors[scene] = noise_floor_snr(ref, alt, self._mask(scene)).as_dict()
        return floors

    def _speed(self, model: ComparedModel, compact) -> None:
        """Evaluations per second of ``model``'s own evaluator, measured once per model
        (the median of repeated timings; their min and max in ``speed_spread``); None for
        an outside model without a Dr.Jit evaluator (``drjit_evaluator()``)."""
        if not self.cfg.speed or model.name in self.results["speed"]:
            return
        if not (isinstance(compact, Compact) or hasattr(compact, "drjit_evaluator")):
            self.results["speed"][model.name] = None
            return
        rate = measure_speed(compact, n=self.cfg.speed_evals,
                             ensemble=getattr(model, "ensemble", None))
        self.results["speed"][model.name] = rate.median
        self.results.setdefault("speed_spread", {})[model.name] = rate.spread()

    def _cell(self, key: str, brdf, model: ComparedModel) -> dict:
        row = {"material": key, "model": model.name}
        try:
            t0 = time.perf_counter()
            compact = model.compress(brdf)
            problem = check_compressed(compact)
            if problem:
                raise TypeError(f"{model.name}: compress() returned a "
                                f"{type(compact).__name__}: {problem}")
            rec = table_of(compact, brdf)
            row["fit_s"] = time.perf_counter() - t0
            if not np.all(np.isfinite(rec)):
                raise FloatingPointError("reconstruction holds NaN/inf")
            row.update(bytes=int(compact.nbytes), rae=rae(brdf.values, rec, brdf.valid),
                       cos_snr=cosine_weighted_snr(brdf.values, rec, brdf.valid),
                       gamma_mse=gamma_mse(brdf.values, rec, brdf.valid))
            info = (getattr(compact, "info", None) or {}) if isinstance(compact, Compact) \
                else {}
            if "transform" in info:
                row["transform"] = info["transform"]
            if self.cfg.render and self.scenes:
                base = self.work / f"{file_stem(key)}__{model.name}"
                if "model" in info:
                    path = str(save_sbrdf(base.parent / f"{base.name}.sbrdf", info["model"],
                                          info.get("version", VERSION)))
                else:
                    path = str(write_merl(base.parent / f"{base.name}.binary",
                                          BRDF(rec, brdf.valid, brdf.name)))
                ref_file = self._reference_file(key, brdf)
                try:
                    row["renders"] = {scene: self._scene_figures(scene, key, model.name,
                                                                 ref_file, path)
                                      for scene in self.scenes}
                finally:  # the decoded table: 35 MB, rendered now, cached as renders
                    if not self.keep_work and path.endswith(".binary"):
                        Path(path).unlink(missing_ok=True)
            if self.cell_speed:
                self._speed(model, compact)
            row["status"] = "finished"
        except Exception as exc:  # noqa: BLE001 - one model's failure never stops the run
            row["status"] = "failed"
            row["error"] = f"{type(exc).__name__}: {one_line(exc)}"
        return row



def seed_mean(per: list[dict]) -> dict:
    """One scene's figures over several seeds: each figure's mean, and for the SNRs and
    HDR-FLIP their standard error (``KEY_se``: sample standard deviation over sqrt(N);
    nan when a seed's figure is not finite) and ``seeds``, N; one seed's figures as they
    are. A figure missing (None) at any seed is None."""
    if len(per) == 1:
        return per[0]
    out: dict = {"seeds": len(per)}
    for k in ("snr_object", "snr_whole", "flip", "render_s"):
        v = [p[k] for p in per]
        if any(x is None for x in v):
            out[k] = None
            continue
        arr = np.array(v, float)
        out[k] = float(arr.mean())
        if k != "render_s":
            out[f"{k}_se"] = (float(arr.std(ddof=1) / np.sqrt(len(arr)))
                              if np.all(np.isfinite(arr)) else
                              0.0 if np.all(arr == arr[0]) else math.nan)
    return out


def _settings(config) -> dict | None:
    """A results file's config without its models (each cell has its own provenance)."""
    return {k: v for k, v in config.items() if k != "models"} if isinstance(config, dict) \
        else None


def _material_task(m, bench: Bench, ens) -> tuple[dict, dict]:
    """A material's error curve and noise floors (reference renders), for any executor."""
    brdf = bench._load(m)
    return bench._curve(brdf, ens), bench._references(material_key(m), brdf)


def _cell_task(item: tuple, bench: Bench) -> dict:
    """One cell (material, model), for any executor."""
    m, model = item
    return bench._cell(material_key(m), bench._load(m), model)
