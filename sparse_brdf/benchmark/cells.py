"""The computations of a bench's cells: for one material, its error curve's reference
renders and noise floors; for one cell (material x model), the model's compression, its
figures in BRDF space, its renders in every scene beside the reference at the same seeds
(both SNR forms, HDR-FLIP, seconds) and the model's speed.

:class:`CellRunner` holds what these share: the config, the scenes that run here and
their object masks, and the ``work/`` folder where renders, decoded tables and FLIP maps
are cached, so that an interrupted bench resumes without rendering again. It is what a
worker runs (:class:`~sparse_brdf.benchmark.bench.Bench` sends it, or a copy without
the results, to an executor); the bench keeps the results file and the reports.
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..coding.fileformat import VERSION, save_sbrdf
from ..compared.compact import Compact
from ..compared.protocol import ComparedModel, check_compressed, table_of
from ..errors import one_line
from ..evaluation.images import read_exr, write_exr
from ..evaluation.render import SHARED_PATHS, noise_floor_snr, object_mask, render_scene
from ..evaluation.scenes import SceneSpec
from ..fileio import atomic_write
from ..metrics import cosine_weighted_snr, gamma_mse, hdr_flip, rae, snr_forms
from ..sources.merl import write_merl
from .bench_config import BenchConfig, file_stem, render_seeds
from .speed import measure_speed

__all__ = ["CellRunner", "seed_mean"]


class CellRunner:
    """The cells' computations for one bench config (see the module doc).

    Parameters
    ----------
    cfg : BenchConfig
        The bench's config (scenes, spp, resolution, seeds, speed settings).
    work : Path
        The folder of cached renders (``work/SCENE/MATERIAL__MODEL.exr``), decoded tables
        and FLIP maps.
    keep_work : bool
        Keep the decoded tables (35 MB each) once rendered.
    results : dict
        Where each model's speed is recorded (``results["speed"]``,
        ``results["speed_spread"]``): the bench's results, or a worker's own.
    """

    def __init__(self, cfg: BenchConfig, work: Path, keep_work: bool, results: dict):
        self.cfg, self.work, self.keep_work, self.results = cfg, work, keep_work, results
        self.scenes: dict[str, SceneSpec] = {}  # scene key -> spec, the scenes that can run
        self._masks: dict[str, np.ndarray] = {}
        self.cell_speed = True  # measure each model's speed in its first cell

    def mask(self, scene: str) -> np.ndarray:
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

    def render(self, scene: str, key: str, filename: str, seed: int,
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

    def scene_figures(self, scene: str, key: str, model: str, ref_file: str,
                       path: str) -> dict:
        """A model's figures in ``scene``: both SNR forms, HDR-FLIP and the render's
        seconds, rendered at each of the bench's seeds (:func:`render_seeds`) beside the
        reference at the same seed; with several seeds, their mean and standard error."""
        per = []
        for i, seed in enumerate(render_seeds(self.cfg)):
            tag = "" if i == 0 else f"@s{seed}"  # the first seed's files keep their names
            ref, _ = self.render(scene, key, ref_file, seed, f"reference{tag}")
            img, secs = self.render(scene, key, path, seed, f"{model}{tag}")
            per.append({**snr_forms(ref, img, self.mask(scene)).as_dict(),
                        "flip": self.flip(scene, key, model, ref, img, keep=i == 0),
                        "render_s": secs})
        return seed_mean(per)

    def flip(self, scene: str, key: str, model: str, ref: np.ndarray,
              img: np.ndarray, keep: bool = True) -> float | None:
        """HDR-FLIP of a model's render over the object's pixels; its error map is kept
        (``keep``) beside the render (``work/SCENE/MATERIAL__MODEL.flip.npy``, float16)
        for the reports. None where FLIP is undefined (a black reference)."""
        try:
            res = hdr_flip(ref, img, self.mask(scene))
        except ValueError as exc:
            print(f"bench: no HDR-FLIP for {key} / {model} in {scene}: {exc}", file=sys.stderr)
            return None
        if not keep:
            return res.mean
        path = self.work / scene / f"{file_stem(key)}__{model}.flip.npy"
        with atomic_write(path, "wb") as f:
            np.save(f, res.map.astype(np.float16))
        return res.mean

    def reference_file(self, key: str, brdf) -> str:
        ref_file = self.work / f"{file_stem(key)}__reference.binary"
        if not ref_file.is_file():
            write_merl(ref_file, brdf)
        return str(ref_file)

    def references(self, key: str, brdf) -> dict:
        """Reference renders of every scene; the noise floor of each (both SNR forms)."""
        floors: dict = {}
        if not self.cfg.render:
            return floors
        ref_file = self.reference_file(key, brdf)
        for scene in self.scenes:
            ref, _ = self.render(scene, key, ref_file, self.cfg.seed, "reference")
            alt, _ = self.render(scene, key, ref_file, self.cfg.noise_seed, "reference-seed2")
            floors[scene] = noise_floor_snr(ref, alt, self.mask(scene)).as_dict()
        return floors

    def speed(self, model: ComparedModel, compact) -> None:
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

    def cell(self, key: str, brdf, model: ComparedModel) -> dict:
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
                ref_file = self.reference_file(key, brdf)
                try:
                    row["renders"] = {scene: self.scene_figures(scene, key, model.name,
                                                                 ref_file, path)
                                      for scene in self.scenes}
                finally:  # the decoded table: 35 MB, rendered now, cached as renders
                    if not self.keep_work and path.endswith(".binary"):
                        Path(path).unlink(missing_ok=True)
            if self.cell_speed:
                self.speed(model, compact)
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
