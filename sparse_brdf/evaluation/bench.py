"""The evaluation harness: models side by side on the same scenes, sampler and seed.

``sparse-brdf bench [CONFIG.toml]`` runs a suite and writes ``results.csv``,
``results.json`` (a versioned schema, :mod:`~sparse_brdf.evaluation.results_file`),
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
(:mod:`~sparse_brdf.model.specs`), built-in or ``module:Class`` from outside the package,
all following :mod:`~sparse_brdf.model.protocol`. A scene whose data is absent (the paper's scene
without the Grace Cathedral map) is skipped with a one-line reason. Each model's speed
is its own evaluation rate (evaluations per second, :mod:`sparse_brdf.speed`).

Fairness: a model that learns from a training set (PCA) is trained only on materials
that the bench does not evaluate; a config that leaves none is refused.
"""

from __future__ import annotations

import contextlib
import copy
import itertools
import json
import os
import shutil
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import tomllib

from ..brdf import BRDF
from ..coords import GRID_BINS
from ..errors import (
    ConfigError,
    MissingDataError,
    MissingFileError,
    SparseBRDFError,
    UsageError,
    one_line,
    short,
)
from ..fileio import atomic_write, require_file
from ..metrics import cosine_weighted_snr, gamma_mse, hdr_flip, rae, snr_forms
from ..model.compact import Compact
from ..model.encode import ENCODE_OPTIONS, error_curve
from ..model.ensemble import resolve_ensemble
from ..model.protocol import ComparedModel, check_compressed, table_of
from ..model.sbrdf import VERSION, min_file_size, save_sbrdf
from ..model.specs import make_model, parse_spec
from ..parallel import Executor, InProcess
from ..params import Interval, check
from ..paths import CONFIGS_DIR
from ..sources.corpora import SPLITS, get_corpus
from ..sources.merl import write_merl
from .html_report import write_html_report
from .render import (
    RENDER_PARAMETERS,
    SHARED_PATHS,
    SceneSpec,
    check_scene_data,
    noise_floor_snr,
    object_mask,
    parse_scene_spec,
    read_exr,
    render_scene,
    write_exr,
)
from .report import write_report
from .results_file import SCHEMA, environment
from .speed import evals_per_second
from .stability import run_stability

__all__ = ["Bench", "BenchConfig", "check_config"]

#: The one-light scene set (``docs/method.md``, "The bench's protocol"): the studio sphere
#: under one distant light at 0, 40 and 70 degrees from the camera.
ONE_LIGHT_SCENES = tuple(f"sphere_light.xml:lightangle={a}" for a in (0, 40, 70))


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
    raise MissingFileError(f"{name}: no such config file, nor a shipped config "
                           f"(shipped: {', '.join(shipped_configs())})")


@dataclass
class BenchConfig:
    """What a bench runs. Every field can be set in a TOML file (same names)."""

    corpora: list[str] = field(default_factory=lambda: ["mitsuba"])
    split: str = "test"
    max_materials: int | None = None  # per corpus
    models: list[str] = field(default_factory=lambda: [
        "sparse:32", "sparse:128", "sparse:262", "sparse:1024", "sparse:262:log-relative",
        "sparse:262:log-relative-cosine", "naive", "cpd:1", "tucker:1x1x1", "pca:40", "pca:300",
        "tabulated"])
    curve_coeffs: list[int] = field(default_factory=lambda: [16, 32, 64, 128, 262, 512, 1024])
    scenes: list[str] = field(default_factory=lambda: [
        "sphere.xml", "paper_sphere.xml", *ONE_LIGHT_SCENES])
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
    #: The file the config was read from (None: the defaults); not a setting (no
    #: annotation), so results do not depend on where the config lives.
    source = None

    @property
    def label(self) -> str:
        """The config as messages name it: its file, or "the default bench config"."""
        return str(self.source) if self.source else "the default bench config"

    def __repr__(self) -> str:
        return (f"BenchConfig(corpora={short(', '.join(self.corpora), 40)!r}, "
                f"split={self.split!r}, {len(self.models)} models, "
                f"scenes={short(', '.join(self.scenes), 40)!r}, spp={self.spp}, "
                f"res={self.res}, out={short(self.out, 40)!r})")

    @classmethod
    def load(cls, path: str | os.PathLike | None) -> BenchConfig:
        """Read a TOML config: a path, or the name of a shipped one (``sparse-brdf bench
        --list``); None gives the defaults."""
        if path is None:
            return cls()
        path, data = read_config(path)
        if data.get("bench", "models") != "models":
            raise ConfigError(f"{path}: bench = {data['bench']!r}: not a model bench config "
                              "(sparse-brdf bench runs it by name)")
        data.pop("bench", None)
        if "scene" in data:  # the one-scene form of earlier configs
            data.setdefault("scenes", [data.pop("scene")])
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ConfigError(f"{path}: unknown bench settings {sorted(unknown)}")
        for key, value in data.items():
            check_setting(path, key, value, cls.__dataclass_fields__[key].type)
        for spec in data.get("models", []) + data.get("stability_models", []):
            _check_model_spec(path, spec)
        for scene in data.get("scenes", []):
            try:
                parse_scene_spec(scene)
            except (UsageError, MissingFileError) as exc:
                raise ConfigError(f"{path}: setting scenes: {exc}") from None
        cfg = cls(**data)
        if cfg.seed == cfg.noise_seed:
            raise ConfigError(f"{path}: setting noise_seed = seed = {cfg.seed}: the noise "
                              "floor compares renders of two different seeds")
        cfg.source = path
        return cfg


#: Largest bench config read (the shipped ones are under 2 kB).
_MAX_CONFIG_BYTES = 1 << 20


def read_config(name: str | os.PathLike) -> tuple[Path, dict]:
    """A bench config's file (a path, or a shipped config's name) and its TOML settings.

    Raises
    ------
    MissingFileError
        If there is no such file nor shipped config.
    ConfigError
        For a file too large or not valid UTF-8 TOML, naming the file.
    """
    path = require_file(find_config(name), "bench config")  # a FIFO would hang
    if path.stat().st_size > _MAX_CONFIG_BYTES:
        raise ConfigError(f"{path}: {path.stat().st_size} bytes: too large for a bench config")
    try:
        return path, tomllib.loads(path.read_bytes().decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not a valid TOML file: {exc}") from exc


def config_kind(name: str | os.PathLike) -> str:
    """What a config benches: its ``bench`` setting, ``"models"`` (the default: models side
    by side, :class:`BenchConfig`) or ``"acquisition"`` (encoding from samples,
    :class:`~sparse_brdf.evaluation.acquisition_bench.AcquisitionConfig`)."""
    kind = read_config(name)[1].get("bench", "models")
    return kind if isinstance(kind, str) else repr(kind)
#: The settings' values (a list setting: each of its items), declared as
#: :mod:`sparse_brdf.params` declarations; the render settings are the renderer's.
SETTINGS = {
    "spp": RENDER_PARAMETERS["spp"], "res": RENDER_PARAMETERS["res"],
    "seed": RENDER_PARAMETERS["seed"], "noise_seed": RENDER_PARAMETERS["seed"],
    "max_materials": Interval(int, 1), "pca_train_max": Interval(int, 2),
    "speed_evals": Interval(int, 1, 1 << 26), "curve_coeffs": GRID_BINS, "split": SPLITS,
}
#: List settings that may not be empty, and why.
_NON_EMPTY = {"curve_coeffs": "give at least one coefficient count (the error curve's "
                              "points)"}
_SETTING_TYPES = {
    "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "str": lambda v: isinstance(v, str),
    "float": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
    "bool": lambda v: isinstance(v, bool),
    "list[str]": lambda v: isinstance(v, list) and all(isinstance(x, str) for x in v),
    "list[int]": lambda v: isinstance(v, list) and all(
        isinstance(x, int) and not isinstance(x, bool) for x in v),
}


def check_setting(path: Path, key: str, value, annotation,
                  declared: dict | None = None) -> None:
    """Raise :class:`ConfigError` unless ``value`` fits the field's type and its
    declaration in ``declared`` (default :data:`SETTINGS`)."""
    kind = str(annotation).removesuffix(" | None")
    if not _SETTING_TYPES.get(kind, lambda v: True)(value):
        raise ConfigError(f"{path}: setting {key} = {value!r}: expected {kind}")
    if key in _NON_EMPTY and value == []:
        raise ConfigError(f"{path}: setting {key} = []: {_NON_EMPTY[key]}")
    declared = SETTINGS if declared is None else declared
    if key in declared:
        for v in value if isinstance(value, list) else [value]:
            try:
                check(f"setting {key}", v, declared[key])
            except UsageError as exc:
                raise ConfigError(f"{path}: {exc}") from None


def _check_model_spec(path: Path, spec) -> None:
    """Raise :class:`ConfigError` unless ``spec`` names a model (the grammar of
    :mod:`sparse_brdf.model.specs`); nothing is read, trained or encoded."""
    try:
        parse_spec(spec)
    except UsageError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def make_models(specs: list[str], ensemble) -> list:
    """The models of ``specs`` (:func:`~sparse_brdf.model.specs.make_model`), unfitted;
    :class:`UsageError` when two share a name (their results would overwrite each other)."""
    models = [make_model(s, ensemble) for s in specs]
    seen: dict[str, str] = {}
    for spec, m in zip(specs, models, strict=True):
        if m.name in seen:
            raise UsageError(f"models {seen[m.name]!r} and {spec!r} are both named "
                             f"{m.name!r}: give each model its own name")
        seen[m.name] = spec
    return models


def evaluated_materials(cfg: BenchConfig) -> list:
    """The materials ``cfg`` evaluates: each corpus's split, at most ``max_materials``."""
    mats = []
    for c in cfg.corpora:
        mats += get_corpus(c).split(cfg.split)[: cfg.max_materials]
    return mats


def training_materials(cfg: BenchConfig, evaluated) -> list:
    """Training materials for learned models: the corpora's training splits, minus every
    evaluated material (a model never sees what it is scored on), at most
    ``pca_train_max``, taken in turn from each corpus (the first of each, then the
    second, ...) so that a capped set still draws on every corpus."""
    seen = {_key(m) for m in evaluated}
    per_corpus = [[m for m in get_corpus(c).split("train") if _key(m) not in seen]
                  for c in cfg.corpora]
    train = [m for rank in itertools.zip_longest(*per_corpus) for m in rank if m is not None]
    return train[: cfg.pca_train_max]


def _check_training_set(cfg: BenchConfig, learners: list, train: list) -> None:
    """:class:`ConfigError` naming the config unless the models that learn (PCA) have at
    least 2 training materials that the bench does not evaluate."""
    if learners and len(train) < 2:
        raise ConfigError(
            f"{cfg.label}: model {learners[0].name} needs at least 2 training materials that "
            f"the bench does not evaluate; corpora {', '.join(cfg.corpora)} with split = "
            f"{cfg.split!r} leave {len(train)} (use split = 'test', or drop the PCA models)")


@contextlib.contextmanager
def _naming(cfg: BenchConfig, setting: str):
    """Re-raise an error of the package (same type) with the config and setting named."""
    try:
        yield
    except SparseBRDFError as exc:
        raise type(exc)(f"{cfg.label}: setting {setting}: {exc}") from exc


def check_config(cfg: BenchConfig) -> dict:
    """Check what a run of ``cfg`` needs, without running, reading a material or writing
    anything: its ensemble, every model (sparse ones over that ensemble), the corpora and
    their split, the training materials of the models that learn, and its scenes (a
    scene whose data is absent would be skipped, and is listed so).

    Parameters
    ----------
    cfg : BenchConfig
        A loaded config (its settings and model specs are checked by
        :meth:`BenchConfig.load`).

    Returns
    -------
    dict
        ``materials`` (evaluated), ``training`` (for the learned models), ``models``
        (names), ``scenes`` (that would run) and ``skipped_scenes`` (name: reason).

    Raises
    ------
    SparseBRDFError
        The first problem, naming the config, the corpus, the scene or the ensemble.
    """
    with _naming(cfg, "ensemble"):
        ens = resolve_ensemble(cfg.ensemble)
    named = ens if cfg.ensemble else None  # none named: each model's own default
    with _naming(cfg, "models"):
        models = make_models(cfg.models, named)
    if not models:
        raise ConfigError(f"{cfg.label}: models = [] lists no model: nothing to bench")
    with _naming(cfg, "stability_models"):
        smodels = make_models(cfg.stability_models, named) if cfg.stability else []
    with _naming(cfg, "corpora"):
        mats = evaluated_materials(cfg)
    _check_byte_budgets(cfg, models + smodels, mats)
    learners = [m for m in models + smodels if m.learns]
    with _naming(cfg, "corpora"):
        train = training_materials(cfg, mats) if learners else []
    _check_training_set(cfg, learners, train)
    scenes, skipped = [], {}
    for name in cfg.scenes if cfg.render else []:
        with _naming(cfg, "scenes"):
            spec = parse_scene_spec(name)
            try:
                check_scene_data(spec.path, spec.params)
            except MissingDataError as exc:
                skipped[spec.key] = str(exc)
                continue
        scenes.append(spec.key)
    return {"materials": len(mats), "training": len(train),
            "models": [m.name for m in models], "scenes": scenes, "skipped_scenes": skipped}


def _check_byte_budgets(cfg: BenchConfig, models: list, mats: list) -> None:
    """:class:`ConfigError` for a model whose byte budget (``sparse-bN``) cannot hold one
    coefficient in the file of some material (its header, name and checksum come first)."""
    for m in models:
        if getattr(m, "n_bytes", None) is None or not mats:
            continue
        floor = max(min_file_size(len(x.name.encode("utf-8")[:255]), m.version) for x in mats)
        if m.n_bytes <= floor:
            raise ConfigError(f"{cfg.label}: model {m.name}: {m.n_bytes} bytes hold no "
                              f"coefficient: a file of these materials takes up to {floor} "
                              "bytes before its first (header, name, checksum)")


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
        self.ensemble = resolve_ensemble(cfg.ensemble)  # read once: provenance and models
        self.results = self._load_results()
        self.scenes: dict[str, SceneSpec] = {}  # scene key -> spec, the scenes that can run
        self._masks: dict[str, np.ndarray] = {}
        self.cell_speed = True  # measure each model's speed in its first cell
        self._loaded: tuple = (None, None)  # the last material loaded (key, BRDF)

    # ------------------------------------------------------------------ bookkeeping
    def _provenance(self) -> dict:
        """What the results depend on beyond the config: the ensemble the sparse models use,
        the encoder's defaults and the .sbrdf version written (all changed between
        versions)."""
        return {"ensemble": self.ensemble.id,
                "encoder_defaults": dict(ENCODE_OPTIONS), "sbrdf_version": VERSION}

    def _load_results(self) -> dict:
        """Earlier results of this config (a resumed run), else a fresh record; results of
        another config, ensemble or encoder are discarded with the renders they cached."""
        p = self.out / "results.json"
        fresh = {"schema": SCHEMA, "config": asdict(self.cfg),
                 "provenance": self._provenance(), "cells": {}, "curves": {},
                 "noise_floor": {}, "speed": {}, "skipped_scenes": {}}
        if p.is_file():
            data = json.loads(p.read_text())
            if all(data.get(k) == fresh[k] for k in ("schema", "config", "provenance")):
                return data
            if self.work.is_dir():  # cached renders and files of the old results
                shutil.rmtree(self.work)
        return fresh

    def _save(self) -> None:
        with atomic_write(self.out / "results.json", "w") as f:
            json.dump(self.results, f, indent=1)

    def materials(self) -> list:
        """The materials the bench evaluates (:func:`evaluated_materials`)."""
        return evaluated_materials(self.cfg)

    def training_materials(self, evaluated) -> list:
        """Training materials for learned models (:func:`training_materials`)."""
        return training_materials(self.cfg, evaluated)

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
        mats = self.materials()
        self._train(models, mats)
        self._run_cells(ex or InProcess(), ens, models, mats)
        missing = [mod for mod in models if mod.name not in self.results["speed"]]
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
                "material": _key(mats[0]),
                "rows": run_stability(mats[0].load(), smodels, self.work / "stability")}
            self._save()
        self.results["environment"] = environment()  # where the last run ran
        self._save()
        write_report(self.results, self.out)
        write_html_report(self.results, self.out)
        return self.results

    def _run_cells(self, ex: Executor, ens, models, mats) -> None:
        """Each material's error curve and reference renders, then every cell, on ``ex``;
        each result is saved as it arrives (so an interrupted bench resumes)."""
        from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `sparse-brdf --help`

        todo_mats = [m for m in mats if _key(m) not in self.results["curves"] or any(
            _key(m) not in self.results["noise_floor"].get(s, {}) for s in self.scenes)]
        todo = [(m, mod) for m in mats for mod in models
                if f"{_key(m)}|{mod.name}" not in self.results["cells"]]
        # closed on an error too, so that the error line starts a line of its own
        with tqdm(total=len(todo) + len(todo_mats), desc="bench",
                  disable=not self.progress) as bar:
            bench = ex.scatter(self._for_workers(ex))
            for i, (curve, floors) in ex.as_completed(_material_task, todo_mats, bench,
                                                      ex.scatter(ens)):
                key = _key(todo_mats[i])
                self.results["curves"][key] = curve
                for scene, floor in floors.items():
                    self.results["noise_floor"].setdefault(scene, {})[key] = floor
                self._save()
                bar.update(1)
            shipped = {name: ex.scatter(mod) for name, mod in {m.name: m for _, m in todo}.items()}
            for i, row in ex.as_completed(_cell_task, [(m, shipped[mod.name]) for m, mod in todo],
                                          bench):
                m, mod = todo[i]
                self.results["cells"][f"{_key(m)}|{mod.name}"] = row
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
        if self._loaded[0] != _key(m):
            self._loaded = (_key(m), m.load())
        return self._loaded[1]

    def _train(self, models, evaluated) -> None:
        needs = [m for m in models if m.learns]
        if not needs:
            return
        train = self.training_materials(evaluated)
        overlap = {_key(m) for m in train} & {_key(m) for m in evaluated}
        assert not overlap, f"training and evaluated materials overlap: {sorted(overlap)}"
        _check_training_set(self.cfg, needs, train)
        brdfs = [m.load() for m in train]
        for m in needs:
            m.fit(brdfs)
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
        exr = self.work / scene / f"{_stem(key)}__{tag}.exr"
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

    def _flip(self, scene: str, key: str, model: str, ref: np.ndarray,
              img: np.ndarray) -> float | None:
        """HDR-FLIP of a model's render over the object's pixels; its error map is kept
        beside the render (``work/SCENE/MATERIAL__MODEL.flip.npy``, float16) for the
        reports. None where FLIP is undefined (a black reference)."""
        try:
            res = hdr_flip(ref, img, self._mask(scene))
        except ValueError as exc:
            print(f"bench: no HDR-FLIP for {key} / {model} in {scene}: {exc}", file=sys.stderr)
            return None
        path = self.work / scene / f"{_stem(key)}__{model}.flip.npy"
        with atomic_write(path, "wb") as f:
            np.save(f, res.map.astype(np.float16))
        return res.mean

    def _reference_file(self, key: str, brdf) -> str:
        ref_file = self.work / f"{_stem(key)}__reference.binary"
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
        """Evaluations per second of ``model``'s own evaluator, measured once per model;
        None for an outside model without a Dr.Jit evaluator (``drjit_evaluator()``)."""
        if not self.cfg.speed or model.name in self.results["speed"]:
            return
        if not (isinstance(compact, Compact) or hasattr(compact, "drjit_evaluator")):
            self.results["speed"][model.name] = None
            return
        self.results["speed"][model.name] = evals_per_second(
            compact, n=self.cfg.speed_evals, ensemble=getattr(model, "ensemble", None))

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
                base = self.work / f"{_stem(key)}__{model.name}"
                if "model" in info:
                    path = str(save_sbrdf(base.with_suffix(".sbrdf"), info["model"],
                                          info.get("version", VERSION)))
                else:
                    path = str(write_merl(base.with_suffix(".binary"),
                                          BRDF(rec, brdf.valid, brdf.name)))
                ref_file = self._reference_file(key, brdf)
                row["renders"] = {}
                for scene in self.scenes:
                    ref, _ = self._render(scene, key, ref_file, self.cfg.seed, "reference")
                    img, secs = self._render(scene, key, path, self.cfg.seed, model.name)
                    row["renders"][scene] = {**snr_forms(ref, img, self._mask(scene)).as_dict(),
                                             "flip": self._flip(scene, key, model.name, ref,
                                                                img),
                                             "render_s": secs}
            if self.cell_speed:
                self._speed(model, compact)
            row["status"] = "finished"
        except Exception as exc:  # noqa: BLE001 - one model's failure never stops the run
            row["status"] = "failed"
            row["error"] = f"{type(exc).__name__}: {exc}"
        return row



def _material_task(m, bench: Bench, ens) -> tuple[dict, dict]:
    """A material's error curve and noise floors (reference renders), for any executor."""
    brdf = bench._load(m)
    return bench._curve(brdf, ens), bench._references(_key(m), brdf)


def _cell_task(item: tuple, bench: Bench) -> dict:
    """One cell (material, model), for any executor."""
    m, model = item
    return bench._cell(_key(m), bench._load(m), model)
