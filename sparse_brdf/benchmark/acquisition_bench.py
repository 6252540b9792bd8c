"""The acquisition bench (``sparse-brdf bench acquisition``): materials recovered from N
measured samples, by the sparse model and by the PCA baseline, rendered in the bench's
scenes against the full table (``docs/results.md``, "Encoding from samples").

Each cell is one fit: a material, a method (``sparse``: :func:`encode_samples` with its
atom prior and PCA fallback; ``pca``: :func:`pca_from_samples`), a placement
(:func:`~sparse_brdf.acquisition.planning.plan`), a sample count N, a sample seed and a noise
level. Samples are simulated from the material's Neural-BRDF network at the pairs
themselves (``measure = "nbrdf"``: a continuous BRDF, as an instrument measures it) or
from its table (``"table"``: each pair gets its bin's value). Every cell is rendered in
every scene with the references' sampler and seed, and scored in both rendering-SNR
forms and in cosine-weighted SNR; the full-table encoding at the same coefficient count
is rendered once per material beside them. Results are saved as each cell finishes, so
an interrupted run resumes; a run with other cells (more seeds, materials or counts)
keeps the finished ones as long as the settings that change a cell's value are the
same. The report (``report.md``) gives the curves (chart: mean over materials, a band
over the seeds), the fit times and the goals checked.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..acquisition import defaults
from ..acquisition.measurements import Samples
from ..acquisition.pca import pca_from_samples
from ..acquisition.planning import PLACEMENTS, add_noise, measure_nbrdf, measure_table, plan
from ..acquisition.recovery import encode_samples
from ..brdf import BRDF
from ..coding.encode import encode
from ..coding.ensemble import resolve_ensemble
from ..coding.fileformat import VERSION, save_sbrdf
from ..coding.spec import DEFAULT_N_COEFFS
from ..errors import ConfigError, SparseBRDFError, one_line
from ..evaluation.images import read_exr, write_exr
from ..evaluation.render import SHARED_PATHS, object_mask, render_scene
from ..evaluation.scenes import RENDER_PARAMETERS, check_scene_data, find_scene
from ..fileio import atomic_write
from ..metrics import cosine_weighted_snr, snr_forms
from ..params import Choice, Interval
from ..sources.corpora import SPLITS, get_corpus
from ..sources.merl import write_merl
from .acquisition_report import write_acquisition_report
from .bench_config import check_setting, read_config

#: The config's ``bench`` setting that selects this bench.
KIND = "acquisition"
#: The compared fits from samples.
METHODS = ("sparse", "pca")
#: How samples are simulated.
MEASURES = ("nbrdf", "table")
#: The settings' values, as :mod:`sparse_brdf.params` declarations.
SETTINGS = {
    "spp": RENDER_PARAMETERS["spp"], "res": RENDER_PARAMETERS["res"],
    "seed": RENDER_PARAMETERS["seed"], "seeds": RENDER_PARAMETERS["seed"],
    "max_materials": Interval(int, 1), "n_samples": Interval(int, 20, 1 << 22),
    "bins_n": Interval(int, 20, 1 << 22), "noise_n": Interval(int, 20, 1 << 22),
    "noise": Interval(float, 0.0, 1.0), "n_coeffs": Interval(int, 1, 1 << 16),
    "placements": Choice(PLACEMENTS), "methods": Choice(METHODS),
    "measure": Choice(MEASURES), "split": SPLITS,
}
#: Settings that change a cell's value: results of other values are discarded.
VALUE_SETTINGS = ("measure", "n_coeffs", "scenes", "spp", "res", "seed", "noise")


@dataclass
class AcquisitionConfig:
    """What the acquisition bench runs; every field can be set in a TOML file (same
    names) beside ``bench = "acquisition"``."""

    bench: str = KIND
    corpus: str = "merl"
    split: str = "test"
    max_materials: int | None = None
    n_samples: list[int] = field(default_factory=lambda: [
        20, 50, 100, 200, 500, 1000, 2000, 5000, 10000, 20000])
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    placements: list[str] = field(default_factory=lambda: ["uniform", "stratified"])
    methods: list[str] = field(default_factory=lambda: list(METHODS))
    bins_n: list[int] = field(default_factory=lambda: [10000])  # at the bins' own positions
    noise: float = 0.02  # multiplicative, relative standard deviation
    noise_n: list[int] = field(default_factory=lambda: [1000])
    measure: str = "nbrdf"
    n_coeffs: int = DEFAULT_N_COEFFS
    ensemble: str | None = None
    scenes: list[str] = field(default_factory=lambda: ["paper_sphere.xml", "sphere.xml"])
    spp: int = 16
    res: int = 128
    seed: int = 0  # the renders' seed
    out: str = "bench_acquisition"
    #: The file the config was read from (None: the defaults); not a setting.
    source = None

    @property
    def label(self) -> str:
        """The config as messages name it."""
        return str(self.source) if self.source else "the default acquisition config"

    @classmethod
    def load(cls, path: str | os.PathLike | None) -> AcquisitionConfig:
        """Read a TOML config (a path or a shipped config's name); None gives the
        defaults.

        Raises
        ------
        ConfigError
            For an unknown setting, a value of the wrong type or out of range, or an
            empty list, naming the file and the setting.
        """
        if path is None:
            return cls()
        path, data = read_config(path)
        if data.get("bench") != KIND:
            raise ConfigError(f"{path}: not an acquisition bench config (it needs "
                              f"bench = {KIND!r})")
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ConfigError(f"{path}: unknown acquisition bench settings {sorted(unknown)}")
        for key, value in data.items():
            check_setting(path, key, value, cls.__dataclass_fields__[key].type, SETTINGS)
            if value == [] and key != "noise_n" and key != "bins_n":
                raise ConfigError(f"{path}: setting {key} = []: give at least one value")
        cfg = cls(**data)
        cfg.source = path
        return cfg


@dataclass(frozen=True)
class Cell:
    """One fit of the bench: which samples and which method."""

    method: str
    placement: str
    n: int
    seed: int
    noise: float = 0.0

    @property
    def key(self) -> str:
        """The cell's name in the results (the material's is prefixed)."""
        return f"{self.method}|{self.placement}|{self.n}|{self.seed}|{self.noise:g}"


def cells(cfg: AcquisitionConfig) -> list[Cell]:
    """Every cell of ``cfg`` for one material: the curves (each placement x N x seed x
    method), the bins' own positions at ``bins_n``, and the noisy samples at
    ``noise_n``; no cell twice."""
    out = [Cell(m, p, n, s) for p in cfg.placements for n in cfg.n_samples
           for s in cfg.seeds for m in cfg.methods]
    out += [Cell(m, "bins", n, s) for n in cfg.bins_n for s in cfg.seeds for m in cfg.methods]
    if cfg.noise > 0:
        out += [Cell(m, p, n, s, cfg.noise) for p in cfg.placements for n in cfg.noise_n
                for s in cfg.seeds for m in cfg.methods]
    return list(dict.fromkeys(out))


def _settings(cfg: AcquisitionConfig, ensemble_id: str) -> dict:
    return {**{k: getattr(cfg, k) for k in VALUE_SETTINGS}, "ensemble": ensemble_id,
            "sbrdf_version": VERSION}


def check_acquisition_config(cfg: AcquisitionConfig) -> dict:
    """Check what a run of ``cfg`` needs without running it: the ensemble, the corpus and
    split, the scenes and the training data of the prior and the PCA basis.

    Returns
    -------
    dict
        ``materials``, ``cells`` (per material), ``scenes`` (that run) and
        ``skipped_scenes`` (name: reason).

    Raises
    ------
    SparseBRDFError
        The first problem, naming the config and the setting.
    """
    try:
        resolve_ensemble(cfg.ensemble)
        mats = get_corpus(cfg.corpus).split(cfg.split)[: cfg.max_materials]
        defaults.training_materials()
    except SparseBRDFError as exc:
        raise type(exc)(f"{cfg.label}: {exc}") from exc
    if not mats:
        raise ConfigError(f"{cfg.label}: corpus {cfg.corpus} has no {cfg.split} materials")
    train = {m.source for m in defaults.training_materials()}
    seen = [m.name for m in mats if m.source in train]
    if seen:
        raise ConfigError(f"{cfg.label}: split = {cfg.split!r} evaluates the prior's and "
                          f"PCA's training materials ({', '.join(seen[:3])}); use 'test'")
    scenes, skipped = [], {}
    for name in cfg.scenes:
        try:
            path = find_scene(name)
            check_scene_data(path)
        except SparseBRDFError as exc:
            skipped[name] = one_line(exc)
            continue
        scenes.append(path.stem)
    if not scenes:
        raise ConfigError(f"{cfg.label}: setting scenes: none can run here "
                          f"({'; '.join(f'{k}: {v}' for k, v in skipped.items())})")
    return {"materials": len(mats), "cells": len(cells(cfg)), "scenes": scenes,
            "skipped_scenes": skipped}


class AcquisitionBench:
    """Runs an :class:`AcquisitionConfig`; results accumulate in ``self.results``."""

    def __init__(self, cfg: AcquisitionConfig, progress: bool = True):
        self.cfg = cfg
        self.out = Path(cfg.out)
        self.work = self.out / "work"
        self.progress = progress
        self.ensemble = resolve_ensemble(cfg.ensemble)
        self.plan = check_acquisition_config(cfg)
        self.scenes = {s: find_scene(s) for s in self.plan["scenes"]}
        self.results = self._load()

    def _load(self) -> dict:
        fresh = {"config": asdict(self.cfg), "settings": _settings(self.cfg, self.ensemble.id),
                 "cells": {}, "full": {}, "references": {},
                 "skipped_scenes": self.plan["skipped_scenes"]}
        path = self.out / "results.json"
        if path.is_file():
            old = json.loads(path.read_text())
            if old.get("settings") == fresh["settings"]:
                old["config"], old["skipped_scenes"] = fresh["config"], fresh["skipped_scenes"]
                return old
            if self.work.is_dir():
                shutil.rmtree(self.work)
        return fresh

    def _save(self) -> None:
        with atomic_write(self.out / "results.json", "w") as f:
            json.dump(self.results, f, indent=1)

    def run(self) -> dict:
        """Run the cells not done yet (saving after each), then write the report."""
        from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `sparse-brdf --help`

        self.work.mkdir(parents=True, exist_ok=True)
        mats = get_corpus(self.cfg.corpus).split(self.cfg.split)[: self.cfg.max_materials]
        todo = {m.name: [c for c in cells(self.cfg)
                         if f"{m.name}|{c.key}" not in self.results["cells"]] for m in mats}
        total = sum(map(len, todo.values())) + sum(
            m.name not in self.results["full"] for m in mats)
        prior = None  # trained once, outside the fits' timings
        if total and "sparse" in self.cfg.methods:
            prior = defaults.default_prior(self.ensemble)
        if total:
            defaults.trained_pca()
        with tqdm(total=total, desc="bench acquisition", disable=not self.progress) as bar:
            for m in mats:
                if not todo[m.name] and m.name in self.results["full"]:
                    continue
                brdf = m.load()
                refs = self._references(m.name, brdf)
                if m.name not in self.results["full"]:
                    self.results["full"][m.name] = self._full(m.name, brdf, refs)
                    self._save()
                    bar.update(1)
                for c in todo[m.name]:
                    bar.set_postfix_str(f"{m.name} {c.method} {c.placement} N={c.n}")
                    row = self._cell(m, brdf, refs, c, prior)
                    self.results["cells"][f"{m.name}|{c.key}"] = row
                    self._save()
                    bar.update(1)
        write_acquisition_report(self.results, self.out)
        return self.results

    # ------------------------------------------------------------------ rendering
    def _references(self, name: str, brdf: BRDF) -> dict:
        """Per scene: the reference render of the full table and the object mask (cached
        in the work folder)."""
        out = {}
        ref_file = self.work / f"{name}__reference.binary"
        if not ref_file.is_file():
            write_merl(ref_file, brdf)
        for scene, path in self.scenes.items():
            exr = self.work / scene / f"{name}__reference.exr"
            mask_file = self.work / scene / "object_mask.npy"
            exr.parent.mkdir(parents=True, exist_ok=True)
            if not exr.is_file():
                write_exr(exr, self._render(path, str(ref_file)))
            if not mask_file.is_file():
                with atomic_write(mask_file, "wb") as f:
                    np.save(f, object_mask(path, res=self.cfg.res,
                                           materials=["material"]))
            out[scene] = (read_exr(exr), np.load(mask_file))
        return out

    def _render(self, path: Path, material: str) -> np.ndarray:
        ens = ({"ensemble": str(Path(self.cfg.ensemble).resolve())}
               if self.cfg.ensemble and material.endswith(".sbrdf")
               and Path(self.cfg.ensemble).exists() else None)
        return render_scene(path, {"material": material}, spp=self.cfg.spp,
                            seed=self.cfg.seed, res=self.cfg.res, sparse_options=ens,
                            sampling=SHARED_PATHS)

    def _score(self, brdf: BRDF, rec: np.ndarray, file: str, refs: dict) -> dict:
        row = {"cos_snr": cosine_weighted_snr(brdf.values, rec, brdf.valid), "renders": {}}
        for scene, (ref, mask) in refs.items():
            img = self._render(self.scenes[scene], file)
            row["renders"][scene] = snr_forms(ref, img, mask).as_dict()
        return row

    def _full(self, name: str, brdf: BRDF, refs: dict) -> dict:
        """The full-table encoding at the bench's coefficient count, scored as a cell."""
        t0 = time.perf_counter()
        model = encode(brdf, self.ensemble, self.cfg.n_coeffs)
        seconds = time.perf_counter() - t0
        path = save_sbrdf(self.work / f"{name}__full.sbrdf", model)
        row = self._score(brdf, model.decode(self.ensemble).values, str(path), refs)
        return {**row, "fit_s": seconds, "coeffs": int(model.n_coeffs.sum())}

    def _samples(self, m, brdf: BRDF, c: Cell) -> Samples:
        wi, wo = plan(c.n, c.placement, c.seed, brdf.shape)
        nbrdf = self.cfg.measure == "nbrdf" and str(m.source).endswith(".h5")
        s = measure_nbrdf(m.source, wi, wo) if nbrdf else measure_table(brdf, wi, wo)
        return add_noise(s, c.noise, seed=c.seed + 1000) if c.noise > 0 else s

    def _cell(self, m, brdf: BRDF, refs: dict, c: Cell, prior) -> dict:
        row: dict = {"material": m.name, **asdict(c)}
        try:
            s = self._samples(m, brdf, c)
            base = self.work / f"{m.name}__{c.key.replace('|', '_')}"
            t0 = time.perf_counter()
            if c.method == "sparse":
                model = encode_samples(s, self.ensemble, self.cfg.n_coeffs, seed=c.seed,
                                       prior=prior)
                row["fit_s"] = time.perf_counter() - t0
                rec = model.decode(self.ensemble).values
                path = save_sbrdf(base.with_suffix(".sbrdf"), model)
                row.update(coeffs=int(model.n_coeffs.sum()),
                           fallback="fallback" in model.stats)
            else:
                pca = pca_from_samples(s, seed=c.seed)
                rec = pca.reconstruct()
                row["fit_s"] = time.perf_counter() - t0
                path = write_merl(base.with_suffix(".binary"), BRDF(rec, brdf.valid, m.name))
                row["components"] = int(pca.info["n_coeffs"])
            if not np.all(np.isfinite(rec)):
                raise FloatingPointError("reconstruction holds NaN/inf")
            row.update(self._score(brdf, rec, str(path), refs))
            path.unlink()
            row["status"] = "finished"
        except Exception as exc:  # noqa: BLE001 - one fit's failure never stops the run
            row.update(status="failed", error=f"{type(exc).__name__}: {one_line(exc)}")
            print(f"bench acquisition: {m.name} {c.key}: {row['error']}", file=sys.stderr)
        return row


__all__ = ["AcquisitionBench", "AcquisitionConfig", "Cell", "cells",
           "check_acquisition_config"]
