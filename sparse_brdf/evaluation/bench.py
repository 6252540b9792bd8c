"""The evaluation harness: models side by side on the same scenes, sampler and seed.

``sparse-brdf bench [CONFIG.toml]`` runs a suite and writes ``results.csv``,
``results.json`` and ``report.md`` with PNG figures into the output folder. Finished
cells (material x model) are kept in ``results.json`` and skipped on a re-run, so an
interrupted bench resumes. Every model is rendered in every scene of the config through
the same sampler and seed as the reference (the full tabulated BRDF), so the Monte Carlo
noise cancels in the difference; each rendering SNR is recorded in both forms
(whole-image, the paper's; object-only, the strict one), beside the noise floor (two
reference renders with different seeds). A scene whose data is absent (the paper's scene
without the Grace Cathedral map) is skipped with a one-line reason. Each model's speed
is its own evaluation rate (evaluations per second, :mod:`sparse_brdf.speed`).

Fairness: a model that learns from a training set (PCA) is trained only on materials
that the bench does not evaluate; a config that leaves none is refused.
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import tomllib

from ..brdf import BRDF
from ..errors import MissingDataError
from ..fileio import atomic_write
from ..metrics import cosine_weighted_snr, gamma_mse, rae, snr_forms
from ..model.baselines import (
    BRDFModel,
    CPDModel,
    NaiveModel,
    PCAModel,
    SparseModel,
    TabulatedModel,
    TuckerModel,
)
from ..model.encode import DEFAULT_N_COEFFS, error_curve
from ..model.ensemble import resolve_ensemble
from ..model.sbrdf import save_sbrdf
from ..paths import CONFIGS_DIR
from ..sources.corpora import get_corpus
from ..sources.merl import write_merl
from .render import (
    check_scene_data,
    find_scene,
    noise_floor_snr,
    object_mask,
    read_exr,
    render_scene,
    write_exr,
)
from .report import write_report
from .speed import evals_per_second
from .stability import run_stability

__all__ = ["Bench", "BenchConfig", "make_model"]


def shipped_configs() -> list[str]:
    """Names of the bench configurations shipped with the package."""
    return sorted(p.stem for p in CONFIGS_DIR.glob("*.toml"))


def find_config(name: str | os.PathLike) -> Path:
    """A config file by path, or a shipped config by name (``full``, ``ci``, ...)."""
    p = Path(name)
    if p.is_file() or p.suffix == ".toml" or len(p.parts) > 1:
        return p
    if (CONFIGS_DIR / f"{p}.toml").is_file():
        return CONFIGS_DIR / f"{p}.toml"
    raise FileNotFoundError(f"{name}: no such config file, nor a shipped config "
                            f"(shipped: {', '.join(shipped_configs())})")


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
    scenes: list[str] = field(default_factory=lambda: ["sphere.xml", "paper_sphere.xml"])
    spp: int = 16
    res: int = 128
    seed: int = 0
    noise_seed: int = 1
    ensemble: str | None = None
    pca_train_max: int | None = None  # cap on PCA training materials (memory: ~17 MB each)
    out: str = "bench_out"
    render: bool = True
    speed: bool = True  # evaluations per second of each model's own evaluator
    speed_evals: int = 1 << 20
    stability: bool = True
    stability_models: list[str] = field(default_factory=lambda: [
        "sparse:262", "naive", "cpd:1", "pca:40"])

    @classmethod
    def load(cls, path: str | os.PathLike | None) -> BenchConfig:
        """Read a TOML config: a path, or the name of a shipped one (``sparse-brdf bench
        --list``); None gives the defaults."""
        if path is None:
            return cls()
        path = find_config(path)
        try:
            with open(path, "rb") as f:
                data = tomllib.load(f)
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"{path}: not a valid TOML file: {exc}") from exc
        if "scene" in data:  # the one-scene form of earlier configs
            data.setdefault("scenes", [data.pop("scene")])
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"{path}: unknown bench settings {sorted(unknown)}")
        return cls(**data)


def make_model(spec: str, ensemble=None) -> BRDFModel:
    """A model from its spec: sparse:N[:TRANSFORM][:OPTIONS], naive, cpd:L, tucker:AxBxC,
    pca:N, tabulated.

    The sparse model's OPTIONS are ``KEY=VALUE`` pairs separated by commas, the keyword
    options of :func:`~sparse_brdf.model.encode.encode` (``ENCODE_OPTIONS``):
    ``selector`` (gamma-mse, render), ``fill`` (missing, invalid), ``fill_iters`` (an
    integer), ``basis`` (rgb, opponent), ``budget`` (channel, joint); TRANSFORM is auto
    (the default), log-plus or log-plus-cosine and may be left out before the options.
    E.g. ``sparse:262``, ``sparse:262:log-plus``,
    ``sparse:262:selector=render,fill=invalid,basis=opponent``,
    ``sparse:262:auto:basis=opponent``. The model's name (the reports' label) lists the
    options not at their defaults: ``sparse-262-selector=render-fill=invalid-basis=opponent``.
    """
    kind, _, arg = spec.partition(":")
    if kind == "sparse":
        return _sparse_model(spec, arg, ensemble)
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


def _sparse_model(spec: str, arg: str, ensemble) -> SparseModel:
    """The sparse model of ``spec`` (``arg``: what follows ``sparse:``; see make_model)."""
    n, *rest = arg.split(":") if arg else [""]
    transform, options = "auto", {}
    for part in rest:
        if "=" not in part and not options and transform == "auto":
            transform = part or "auto"
            continue
        for item in filter(None, part.split(",")):
            key, eq, value = (x.strip() for x in item.partition("="))
            if not eq or key in options:
                raise ValueError(f"model {spec!r}: expected distinct KEY=VALUE options, "
                                 f"got {item!r}")
            if key == "fill_iters":
                if not value.isdigit():
                    raise ValueError(f"model {spec!r}: fill_iters must be an integer >= 0, "
                                     f"got {value!r}")
                value = int(value)
            options[key] = value
    return SparseModel(ensemble, int(n or DEFAULT_N_COEFFS), transform, **options)


def _key(m) -> str:
    return f"{m.corpus}/{m.name}"


def _stem(key: str) -> str:
    return key.replace("/", "__")


class Bench:
    """Runs a :class:`BenchConfig`; results accumulate in ``self.results``."""

    def __init__(self, cfg: BenchConfig, progress: bool = True):
        self.cfg = cfg
        self.out = Path(cfg.out)
        self.work = self.out / "work"
        self.progress = progress
        self.results = self._load_results()
        self.scenes: dict[str, Path] = {}  # scene name -> path, the scenes that can run
        self._masks: dict[str, np.ndarray] = {}

    # ------------------------------------------------------------------ bookkeeping
    def _load_results(self) -> dict:
        p = self.out / "results.json"
        if p.is_file():
            data = json.loads(p.read_text())
            if data.get("config") == asdict(self.cfg):
                return data
        return {"config": asdict(self.cfg), "cells": {}, "curves": {}, "noise_floor": {},
                "speed": {}, "skipped_scenes": {}}

    def _save(self) -> None:
        with atomic_write(self.out / "results.json", "w") as f:
            json.dump(self.results, f, indent=1)

    def materials(self):
        mats = []
        for c in self.cfg.corpora:
            mats += get_corpus(c).split(self.cfg.split)[: self.cfg.max_materials]
        return mats

    def training_materials(self, evaluated) -> list:
        """Training materials for learned models: the corpora's training splits, minus
        every evaluated material (a model never sees what it is scored on)."""
        seen = {_key(m) for m in evaluated}
        train = []
        for c in self.cfg.corpora:
            train += [m for m in get_corpus(c).split("train") if _key(m) not in seen]
        return train[: self.cfg.pca_train_max]

    def _resolve_scenes(self) -> None:
        """The config's scenes that can run here; the others are skipped with a reason."""
        for name in self.cfg.scenes:
            path = find_scene(name)
            try:
                check_scene_data(path)
            except MissingDataError as exc:
                self.results["skipped_scenes"][path.stem] = str(exc)
                print(f"bench: skipping scene {path.name}: {exc}", file=sys.stderr)
                continue
            self.scenes[path.stem] = path

    # ------------------------------------------------------------------ running
    def run(self) -> dict:
        from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `sparse-brdf --help`

        self.out.mkdir(parents=True, exist_ok=True)
        self.work.mkdir(parents=True, exist_ok=True)
        if self.cfg.render:
            self._resolve_scenes()
        ens = resolve_ensemble(self.cfg.ensemble)
        models = [make_model(s, ens) for s in self.cfg.models]
        mats = self.materials()
        self._train(models, mats)
        todo = [(m, mod) for m in mats for mod in models
                if f"{_key(m)}|{mod.name}" not in self.results["cells"]]
        bar = tqdm(total=len(todo) + len(mats), desc="bench", disable=not self.progress)
        for m in mats:
            key = _key(m)
            brdf = None
            if key not in self.results["curves"] or any(
                    key not in self.results["noise_floor"].get(s, {}) for s in self.scenes):
                brdf = m.load()
                self.results["curves"][key] = self._curve(brdf, ens)
                self._references(key, brdf)
                self._save()
            bar.update(1)
            for mod in models:
                cell = f"{key}|{mod.name}"
                if cell in self.results["cells"]:
                    continue
                brdf = brdf or m.load()
                self.results["cells"][cell] = self._cell(key, brdf, mod)
                self._save()
                bar.update(1)
        bar.close()
        missing = [mod for mod in models if mod.name not in self.results["speed"]]
        if self.cfg.speed and missing and mats:  # e.g. measurements deleted to redo them
            brdf = mats[0].load()
            for mod in missing:
                self._speed(mod, mod.fit(brdf))
                self._save()
        if self.cfg.stability and "stability" not in self.results and mats:
            smodels = [make_model(s, ens) for s in self.cfg.stability_models]
            self._train(smodels, mats)
            self.results["stability"] = {
                "material": _key(mats[0]),
                "rows": run_stability(mats[0].load(), smodels, self.work / "stability")}
            self._save()
        write_report(self.results, self.out)
        return self.results

    def _train(self, models, evaluated) -> None:
        needs = [m for m in models if isinstance(m, PCAModel)]
        if not needs:
            return
        train = self.training_materials(evaluated)
        overlap = {_key(m) for m in train} & {_key(m) for m in evaluated}
        assert not overlap, f"training and evaluated materials overlap: {sorted(overlap)}"
        if len(train) < 2:
            raise ValueError(
                f"{needs[0].name}: needs at least 2 training materials that the bench does not "
                f"evaluate; corpora {self.cfg.corpora} with split = {self.cfg.split!r} leave "
                f"{len(train)} (use split = 'test', or drop the PCA models)")
        brdfs = [m.load() for m in train]
        for m in needs:
            m.train(brdfs)
            m.trained_on = [_key(t) for t in train]

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
                mask = object_mask(self.scenes[scene], res=self.cfg.res)
                path.parent.mkdir(parents=True, exist_ok=True)
                with atomic_write(path, "wb") as f:
                    np.save(f, mask)
            self._masks[scene] = mask
        return self._masks[scene]

    def _render(self, scene: str, key: str, filename: str, seed: int,
                tag: str) -> tuple[np.ndarray, float]:
        exr = self.work / scene / f"{_stem(key)}__{tag}.exr"
        if exr.is_file():
            meta = json.loads(exr.with_suffix(".json").read_text())
            return read_exr(exr), meta["seconds"]
        t0 = time.perf_counter()
        # coefficient files decode with the bench's ensemble, not the shipped default
        ens = ({"ensemble": str(Path(self.cfg.ensemble).resolve())}
               if self.cfg.ensemble and filename.endswith(".sbrdf") else None)
        img = render_scene(self.scenes[scene], {"material": filename}, spp=self.cfg.spp,
                           seed=seed, res=self.cfg.res, sparse_options=ens)
        seconds = time.perf_counter() - t0
        write_exr(exr, img)
        with atomic_write(exr.with_suffix(".json"), "w") as f:
            json.dump({"seconds": seconds}, f)
        return img, seconds

    def _reference_file(self, key: str, brdf) -> str:
        ref_file = self.work / f"{_stem(key)}__reference.binary"
        if not ref_file.is_file():
            write_merl(ref_file, brdf)
        return str(ref_file)

    def _references(self, key: str, brdf) -> None:
        """Reference renders of every scene, and the noise floor (both SNR forms)."""
        if not self.cfg.render:
            return
        ref_file = self._reference_file(key, brdf)
        for scene in self.scenes:
            ref, _ = self._render(scene, key, ref_file, self.cfg.seed, "reference")
            alt, _ = self._render(scene, key, ref_file, self.cfg.noise_seed, "reference-seed2")
            self.results["noise_floor"].setdefault(scene, {})[key] = noise_floor_snr(
                ref, alt, self._mask(scene)).as_dict()

    def _speed(self, model: BRDFModel, compact) -> None:
        """Evaluations per second of ``model``'s own evaluator, measured once per model."""
        if not self.cfg.speed or model.name in self.results["speed"]:
            return
        self.results["speed"][model.name] = evals_per_second(
            compact, n=self.cfg.speed_evals, ensemble=getattr(model, "ensemble", None))

    def _cell(self, key: str, brdf, model: BRDFModel) -> dict:
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
            if self.cfg.render and self.scenes:
                base = self.work / f"{_stem(key)}__{model.name}"
                if compact.info and "model" in compact.info:
                    path = str(save_sbrdf(base.with_suffix(".sbrdf"), compact.info["model"]))
                else:
                    path = str(write_merl(base.with_suffix(".binary"),
                                          BRDF(rec, brdf.valid, brdf.name)))
                ref_file = self._reference_file(key, brdf)
                row["renders"] = {}
                for scene in self.scenes:
                    ref, _ = self._render(scene, key, ref_file, self.cfg.seed, "reference")
                    img, secs = self._render(scene, key, path, self.cfg.seed, model.name)
                    row["renders"][scene] = {**snr_forms(ref, img, self._mask(scene)).as_dict(),
                                             "render_s": secs}
            self._speed(model, compact)
            row["status"] = "finished"
        except Exception as exc:  # noqa: BLE001 - one model's failure never stops the run
            row["status"] = "failed"
            row["error"] = f"{type(exc).__name__}: {exc}"
        return row

