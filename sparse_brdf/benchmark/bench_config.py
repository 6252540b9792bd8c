"""The bench's configuration: the shipped configs and where a config is found, the
:class:`BenchConfig` settings with their types and checks, and the checks of a whole
config (its models, materials and scenes) before any work (``docs/benchmarks.md``).
"""

from __future__ import annotations

import contextlib
import itertools
import os
from dataclasses import dataclass, field
from pathlib import Path

import tomllib

from ..coding.ensemble import resolve_ensemble
from ..coding.fileformat import min_file_size
from ..compared.sparse_model import SparseModel
from ..compared.specs import make_model, parse_spec
from ..coords import GRID_BINS
from ..errors import (
    ConfigError,
    MissingDataError,
    MissingFileError,
    SparseBRDFError,
    UsageError,
    short,
)
from ..evaluation.scenes import RENDER_PARAMETERS, check_scene_data, parse_scene_spec
from ..fileio import require_file
from ..params import Interval, check
from ..paths import CONFIGS_DIR
from ..sources.corpora import SPLITS, get_corpus

__all__ = ["BenchConfig", "check_config", "config_kind", "read_config", "render_seeds",
           "shipped_configs"]

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
    seeds: int = 1  # renders per cell and scene, at seeds from seed on (noise_seed skipped)
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
    :class:`~sparse_brdf.benchmark.acquisition_bench.AcquisitionConfig`)."""
    kind = read_config(name)[1].get("bench", "models")
    return kind if isinstance(kind, str) else repr(kind)
#: The settings' values (a list setting: each of its items), declared as
#: :mod:`sparse_brdf.params` declarations; the render settings are the renderer's.
SETTINGS = {
    "spp": RENDER_PARAMETERS["spp"], "res": RENDER_PARAMETERS["res"],
    "seed": RENDER_PARAMETERS["seed"], "noise_seed": RENDER_PARAMETERS["seed"],
    "max_materials": Interval(int, 1), "pca_train_max": Interval(int, 2),
    "speed_evals": Interval(int, 1, 1 << 26), "seeds": Interval(int, 1, 64),
    "curve_coeffs": GRID_BINS, "split": SPLITS,
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
    :mod:`sparse_brdf.compared.specs`); nothing is read, trained or encoded."""
    try:
        parse_spec(spec)
    except UsageError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def make_models(specs: list[str], ensemble) -> list:
    """The models of ``specs`` (:func:`~sparse_brdf.compared.specs.make_model`), unfitted;
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


def learners_training_set(cfg: BenchConfig, evaluated) -> list:
    """Training materials for learned models: the corpora's training splits, minus every
    evaluated material (a model never sees what it is scored on), at most
    ``pca_train_max``, taken in turn from each corpus (the first of each, then the
    second, ...) so that a capped set still draws on every corpus."""
    seen = {material_key(m) for m in evaluated}
    per_corpus = [[m for m in get_corpus(c).split("train") if material_key(m) not in seen]
                  for c in cfg.corpora]
    train = [m for rank in itertools.zip_longest(*per_corpus) for m in rank if m is not None]
    return train[: cfg.pca_train_max]


def check_training_set(cfg: BenchConfig, learners: list, train: list) -> None:
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
        train = learners_training_set(cfg, mats) if learners else []
    check_training_set(cfg, learners, train)
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
    coefficient in the file of some material (its header, name and checksum come first).
    Only the package's sparse model has such a budget: an outside model's own ``n_bytes``
    attribute, if it has one, means what that model says."""
    for m in models:
        if not isinstance(m, SparseModel) or m.n_bytes is None or not mats:
            continue
        floor = max(min_file_size(len(x.name.encode("utf-8")[:255]), m.version) for x in mats)
        if m.n_bytes <= floor:
            raise ConfigError(f"{cfg.label}: model {m.name}: {m.n_bytes} bytes hold no "
                              f"coefficient: a file of these materials takes up to {floor} "
                              "bytes before its first (header, name, checksum)")


def render_seeds(cfg: BenchConfig) -> list[int]:
    """The seeds each cell is rendered at: ``cfg.seeds`` of them, from ``cfg.seed`` on,
    skipping ``cfg.noise_seed`` (the noise floor's second reference)."""
    seeds, s = [], cfg.seed
    while len(seeds) < cfg.seeds:
        if s != cfg.noise_seed:
            seeds.append(s)
        s += 1
    return seeds


def material_key(m) -> str:
    """A material's key in the results: ``corpus/name``."""
    return f"{m.corpus}/{m.name}"


def file_stem(key: str) -> str:
    """A results key as a file name's stem."""
    return key.replace("/", "__")
