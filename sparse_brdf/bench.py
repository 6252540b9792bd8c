"""The evaluation harness: models side by side on the same scenes, sampler and seed.

``sparse-brdf bench [CONFIG.toml]`` runs a suite and writes ``results.csv``,
``results.json`` and ``report.md`` with PNG figures into the output folder. Finished
cells (material x model) are kept in ``results.json`` and skipped on a re-run, so an
interrupted bench resumes. Every model is rendered through the same scene, sampler and
seed as the reference (the full tabulated BRDF), so the Monte Carlo noise cancels in the
difference; the noise floor (two reference renders with different seeds) is reported
beside every SNR.
"""

from __future__ import annotations

import csv
import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import tomllib

from .baselines import (
    BRDFModel,
    CPDModel,
    NaiveModel,
    PCAModel,
    SparseModel,
    TabulatedModel,
    TuckerModel,
)
from .corpora import get_corpus
from .fileio import atomic_write
from .metrics import cosine_weighted_snr, gamma_mse, rae

SCENES_DIR = Path(__file__).resolve().parent.parent / "scenes"


@dataclass
class BenchConfig:
    """What a bench runs. Every field can be set in a TOML file (same names)."""

    corpora: list[str] = field(default_factory=lambda: ["mitsuba"])
    split: str = "test"
    max_materials: int | None = None  # per corpus
    models: list[str] = field(default_factory=lambda: [
        "sparse:32", "sparse:128", "sparse:262", "sparse:1024", "sparse:262:log-plus",
        "sparse:262:log-plus-cosine", "naive", "cpd:1", "tucker:1x1x1", "pca:40", "pca:300",
        "tabulated"])
    curve_coeffs: list[int] = field(default_factory=lambda: [16, 32, 64, 128, 262, 512, 1024])
    scene: str = "sphere.xml"
    spp: int = 16
    res: int = 128
    seed: int = 0
    noise_seed: int = 1
    ensemble: str | None = None
    pca_train_max: int | None = None  # cap on PCA training materials (memory: ~17 MB each)
    out: str = "bench_out"
    render: bool = True
    stability: bool = True
    stability_models: list[str] = field(default_factory=lambda: [
        "sparse:262", "naive", "cpd:1", "pca:40"])

    @classmethod
    def load(cls, path: str | os.PathLike | None) -> BenchConfig:
        if path is None:
            return cls()
        with open(path, "rb") as f:
            data = tomllib.load(f)
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"{path}: unknown bench settings {sorted(unknown)}")
        return cls(**data)


def make_model(spec: str, ensemble=None) -> BRDFModel:
    """A model from its spec: sparse:N[:TRANSFORM], naive, cpd:L, tucker:AxBxC, pca:N,
    tabulated."""
    kind, _, arg = spec.partition(":")
    if kind == "sparse":
        n, _, transform = arg.partition(":")
        return SparseModel(ensemble, int(n or 262), transform or "auto")
    if kind == "naive":
        return NaiveModel()
    if kind == "cpd":
        return CPDModel(int(arg or 1))
    if kind == "tucker":
        return TuckerModel(tuple(int(x) for x in (arg or "1x1x1").split("x")))
    if kind == "pca":
        return PCAModel(int(arg or 40))
    if kind == "tabulated":
        return TabulatedModel()
    raise ValueError(f"unknown model {spec!r}: use sparse:N, naive, cpd:L, tucker:AxBxC, "
                     "pca:N or tabulated")


def _scene_path(cfg: BenchConfig) -> Path:
    p = Path(cfg.scene)
    return p if p.is_file() else SCENES_DIR / cfg.scene


class Bench:
    """Runs a :class:`BenchConfig`; results accumulate in ``self.results``."""

    def __init__(self, cfg: BenchConfig, progress: bool = True):
        self.cfg = cfg
        self.out = Path(cfg.out)
        self.work = self.out / "work"
        self.progress = progress
        self.results = self._load_results()

    # ------------------------------------------------------------------ bookkeeping
    def _load_results(self) -> dict:
        p = self.out / "results.json"
        if p.is_file():
            data = json.loads(p.read_text())
            if data.get("config") == asdict(self.cfg):
                return data
        return {"config": asdict(self.cfg), "cells": {}, "curves": {}, "noise_floor": {}}

    def _save(self) -> None:
        with atomic_write(self.out / "results.json", "w") as f:
            json.dump(self.results, f, indent=1)

    def materials(self):
        mats = []
        for c in self.cfg.corpora:
            mats += get_corpus(c).split(self.cfg.split)[: self.cfg.max_materials]
        return mats

    # ------------------------------------------------------------------ running
    def run(self) -> dict:
        from tqdm.auto import tqdm

        from .ensemble import Ensemble

        self.out.mkdir(parents=True, exist_ok=True)
        self.work.mkdir(parents=True, exist_ok=True)
        ens = Ensemble.load(self.cfg.ensemble) if self.cfg.ensemble else Ensemble.default()
        models = [make_model(s, ens) for s in self.cfg.models]
        self._train(models)
        mats = self.materials()
        todo = [(m, mod) for m in mats for mod in models
                if f"{m.corpus}/{m.name}|{mod.name}" not in self.results["cells"]]
        bar = tqdm(total=len(todo) + len(mats), desc="bench", disable=not self.progress)
        for m in mats:
            key = f"{m.corpus}/{m.name}"
            brdf = None
            if key not in self.results["curves"] or (
                    self.cfg.render and key not in self.results["noise_floor"]):
                brdf = m.load()
                self._curve(key, brdf, ens)
                if self.cfg.render:
                    self._reference(key, m)
                self._save()
            bar.update(1)
            for mod in models:
                cell = f"{key}|{mod.name}"
                if cell in self.results["cells"]:
                    continue
                brdf = brdf or m.load()
                self.results["cells"][cell] = self._cell(key, m, brdf, mod)
                self._save()
                bar.update(1)
        bar.close()
        if self.cfg.stability and "stability" not in self.results and mats:
            from .stability import run_stability

            smodels = [make_model(s, ens) for s in self.cfg.stability_models]
            self._train(smodels)
            self.results["stability"] = {
                "material": f"{mats[0].corpus}/{mats[0].name}",
                "rows": run_stability(mats[0].load(), smodels, self.work / "stability")}
            self._save()
        from .report import write_report

        write_report(self.results, self.out)
        return self.results

    def _train(self, models) -> None:
        needs = [m for m in models if isinstance(m, PCAModel)]
        if not needs:
            return
        train = []
        for c in self.cfg.corpora:
            train += get_corpus(c).split("train")[: self.cfg.pca_train_max]
        brdfs = [m.load() for m in train]
        for m in needs:
            m.train(brdfs)

    def _curve(self, key, brdf, ens) -> None:
        """Error against coefficients and the transform choices (Fig. 2, Table 2)."""
        from .encode import error_curve

        self.results["curves"][key] = error_curve(brdf, ens, self.cfg.curve_coeffs)

    def _render(self, key, m, filename: str, seed: int, tag: str) -> tuple[np.ndarray, float]:
        from .render import read_exr, render_scene, write_exr

        exr = self.work / f"{key.replace('/', '__')}__{tag}.exr"
        if exr.is_file():
            meta = json.loads(exr.with_suffix(".json").read_text())
            return read_exr(exr), meta["seconds"]
        t0 = time.perf_counter()
        img = render_scene(_scene_path(self.cfg), {"material": filename}, spp=self.cfg.spp,
                           seed=seed, res=self.cfg.res)
        seconds = time.perf_counter() - t0
        write_exr(exr, img)
        exr.with_suffix(".json").write_text(json.dumps({"seconds": seconds}))
        return img, seconds

    def _reference(self, key, m) -> None:
        from .merl import write_merl

        ref_file = self.work / f"{key.replace('/', '__')}__reference.binary"
        if not ref_file.is_file():
            write_merl(ref_file, m.load())
        ref, _ = self._render(key, m, str(ref_file), self.cfg.seed, "reference")
        alt, _ = self._render(key, m, str(ref_file), self.cfg.noise_seed, "reference-seed2")
        from .metrics import render_snr

        self.results["noise_floor"][key] = render_snr(ref, alt)

    def _cell(self, key, m, brdf, model: BRDFModel) -> dict:
        from .merl import write_merl
        from .metrics import render_snr
        from .sbrdf import save_sbrdf

        row = {"material": key, "model": model.name}
        try:
            t0 = time.perf_counter()
            compact = model.fit(brdf)
            rec = compact.reconstruct()
            row["fit_s"] = time.perf_counter() - t0
            if not np.all(np.isfinite(rec)):
                raise FloatingPointError("reconstruction holds NaN/inf")
            row.update(bytes=compact.nbytes, rae=rae(brdf.values, rec, brdf.valid),
                       cos_snr=cosine_weighted_snr(brdf.values, rec, brdf.valid),
                       gamma_mse=gamma_mse(brdf.values, rec, brdf.valid))
            if compact.info and "transform" in compact.info:
                row["transform"] = compact.info["transform"]
            if self.cfg.render:
                base = self.work / f"{key.replace('/', '__')}__{model.name}"
                if compact.info and "model" in compact.info:
                    path = str(save_sbrdf(base.with_suffix(".sbrdf"), compact.info["model"]))
                else:
                    from .brdf import BRDF

                    path = str(write_merl(base.with_suffix(".binary"),
                                          BRDF(rec, brdf.valid, brdf.name)))
                ref, _ = self._render(key, m, str(self.work / f"{key.replace('/', '__')}"
                                                    "__reference.binary"),
                                      self.cfg.seed, "reference")
                img, secs = self._render(key, m, path, self.cfg.seed, model.name)
                row.update(render_snr=render_snr(ref, img), render_s=secs)
            row["status"] = "finished"
        except Exception as exc:  # noqa: BLE001 - one model's failure never stops the run
            row["status"] = "failed"
            row["error"] = f"{type(exc).__name__}: {exc}"
        return row


def write_csv(results: dict, path: Path) -> None:
    rows = list(results["cells"].values())
    keys = sorted({k for r in rows for k in r})
    with atomic_write(path, "w") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
