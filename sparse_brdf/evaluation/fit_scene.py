"""Model no more than a scene needs: per-material coefficient budgets for a target SNR.

For every measured material of a scene, :func:`fit_scene`

1. *predicts* the fewest coefficients per channel (from a ladder 16, 32, ..., 4096) whose
   BRDF-space proxy reaches the target: predicted rendering SNR = cosine-weighted SNR +
   ``offset``, the offset calibrated on bench results (``benchmarks/calibrate.py``
   writes ``sparse_brdf/data/snr_calibration.json``; 0 dB without it);
2. *verifies* with a low-spp render of the scene in which only that material is the
   sparse model and every other material is tabulated, against the all-tabulated
   reference (same seed and sampling, so the noise cancels); the SNR it targets is the
   object-only one (pixels whose camera rays hit geometry), the whole-image SNR is
   recorded beside it;
3. *refines*: climbs the ladder until the verified SNR reaches the target (or the
   ladder ends), and steps down while a smaller budget still verifies; then renders the
   scene with every material sparse and, while that misses the target (the materials'
   errors add up), raises the per-material target by the shortfall and refines again.

It writes one ``.sbrdf`` per material and ``fit-scene.md`` / ``fit-scene.json``.
"""

from __future__ import annotations

import json
import os
import time
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..fileio import atomic_write
from ..metrics import OBJECT_ONLY, WHOLE_IMAGE, SNRForms, cosine_weighted_snr, snr_forms
from ..model.encode import DEFAULT_N_COEFFS, choose_transform, project_all, select
from ..model.ensemble import Ensemble, resolve_ensemble
from ..model.layouts import channel_terms, grouped_bytes, strict_channel
from ..model.sbrdf import file_size, save_sbrdf
from ..model.sparse import SparseBRDF
from ..paths import CALIBRATION_PATH
from ..sources.load import load_brdf
from ..transforms import TRANSFORMS
from .render import object_mask, render_scene

LADDER: tuple[int, ...] = (16, 32, 64, 128, 262, 512, 1024, 2048, 4096)


def calibration_offset() -> float:
    """dB to add to the cosine-weighted BRDF SNR to predict the rendering SNR."""
    if CALIBRATION_PATH.is_file():
        return float(json.loads(CALIBRATION_PATH.read_text())["offset_db"])
    return 0.0


def scene_materials(scene: str | os.PathLike, overrides: Mapping[str, str]) -> dict[str, str]:
    """Measured materials of a scene: ``tabulated_brdf``/``sparse_brdf`` BSDFs with a
    ``filename`` in the XML (by id), then ``overrides`` (id -> source) on top."""
    root = ET.parse(scene).getroot()
    found = {}
    for el in root.iter("bsdf"):
        if el.get("type") in ("tabulated_brdf", "sparse_brdf") and el.get("id"):
            for s in el.iter("string"):
                if s.get("name") == "filename":
                    path = Path(s.get("value", ""))
                    if not path.is_absolute():
                        path = Path(scene).parent / path
                    found[el.get("id")] = str(path)
    found.update(overrides)
    if not found:
        raise ValueError(f"{scene}: no measured materials: give them with --material ID=FILE")
    return found


def _predict(brdf, ens, ladder, target, offset):
    """Models and predicted SNRs along the ladder; index of the first predicted >= target."""
    proj = {t: project_all(brdf, ens, t, max(ladder)) for t in TRANSFORMS}
    cands, preds = [], []
    for n in ladder:
        m = choose_transform(brdf, {t: select(proj[t], n, name=brdf.name) for t in TRANSFORMS},
                             ens)
        rec = m.decode(ens, valid=brdf.valid).values
        cands.append(m)
        preds.append(cosine_weighted_snr(brdf.values, rec, brdf.valid) + offset)
    hit = [i for i, p in enumerate(preds) if p >= target]
    return cands, preds, (hit[0] if hit else len(ladder) - 1)


@dataclass
class _Fit:
    """One material's state: its candidate models along the ladder, their predicted SNRs,
    the SNRs verified so far and the ladder index currently chosen."""

    brdf: BRDF
    candidates: list[SparseBRDF]
    predicted: list[float]  # dB, one per candidate
    chosen: int
    verified: dict[int, SNRForms] = field(default_factory=dict)  # ladder index -> SNRs

    @property
    def at_top(self) -> bool:
        """Whether the choice is the ladder's last (largest) budget."""
        return self.chosen == len(self.candidates) - 1


@dataclass
class _Scene:
    """Verification renders of a scene: every material tabulated but the overridden ones,
    with the reference's spp, seed and resolution, so the Monte Carlo noise cancels."""

    path: str | os.PathLike
    materials: dict[str, str]  # id -> measured source
    spp: int
    res: int
    seed: int
    sparse_options: dict | None
    reference: np.ndarray | None = None
    mask: np.ndarray | None = None

    def render(self, materials: Mapping[str, str]) -> np.ndarray:
        return render_scene(self.path, materials, spp=self.spp, seed=self.seed, res=self.res,
                            sparse_options=self.sparse_options)

    def snr(self, overrides: Mapping[str, str]) -> SNRForms:
        """SNRs of the scene with ``overrides`` (id -> file) against the reference."""
        return snr_forms(self.reference, self.render({**self.materials, **overrides}),
                         self.mask)


def fit_scene(
    scene: str | os.PathLike,
    target_snr: float,
    overrides: Mapping[str, str] | None = None,
    out: str | os.PathLike = "fit_scene_out",
    ensemble: Ensemble | None = None,
    ensemble_path: str | None = None,
    spp: int = 8,
    res: int = 64,
    seed: int = 0,
    ladder: Sequence[int] = LADDER,
    progress: bool = True,
) -> dict:
    """Fit every measured material of ``scene`` to ``target_snr`` dB; see module doc."""
    ens = ensemble or resolve_ensemble(ensemble_path)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    mats = scene_materials(scene, overrides or {})
    offset = calibration_offset()
    opts = {"ensemble": ensemble_path} if ensemble_path else None
    t0 = time.perf_counter()
    scn = _Scene(scene, mats, spp, res, seed, opts)
    scn.reference = scn.render(mats)
    scn.mask = object_mask(scene, res=res)
    fits = {}
    for mid, src in mats.items():
        brdf = load_brdf(src)
        fits[mid] = _Fit(brdf, *_predict(brdf, ens, list(ladder), target_snr, offset))
    rounds = _fit_rounds(fits, scn, out, target_snr, progress)
    rows = [_material_row(mid, fit, mats[mid], out, ens, ladder, progress)
            for mid, fit in fits.items()]
    report = {
        "scene": str(scene), "target_snr": target_snr, "offset_db": offset, "spp": spp,
        "res": res, "seed": seed, "materials": rows,
        "scene_snr_all_sparse": rounds[-1]["scene_snr"],
        "scene_snr_all_sparse_whole": rounds[-1]["scene_snr_whole"], "rounds": rounds,
        "bytes_total": sum(r["bytes"] for r in rows),
        # the key keeps its name (262 = DEFAULT_N_COEFFS) for readers of earlier reports
        "bytes_fixed_262": sum(file_size(3 * DEFAULT_N_COEFFS, len(r["id"])) for r in rows),
        "bytes_tabulated_merl": len(rows) * (12 + 8 * 3 * int(np.prod(ens.shape))),
        "memory_strict_total": sum(r["memory_strict"] for r in rows),
        "memory_tabulated_total": sum(r["memory_tabulated"] for r in rows),
        "seconds": time.perf_counter() - t0,
    }
    _write(report, out)
    return report


def _verify(mid: str, fit: _Fit, k: int, scn: _Scene, out: Path) -> float:
    """Object-only SNR of the scene with only ``mid`` sparse at ladder index ``k``
    (rendered once per index)."""
    if k not in fit.verified:
        path = save_sbrdf(out / f"{mid}.candidate.sbrdf", fit.candidates[k])
        fit.verified[k] = scn.snr({mid: str(path)})
    return fit.verified[k].object


def _fit_rounds(fits: dict[str, _Fit], scn: _Scene, out: Path, target_snr: float,
                progress: bool) -> list[dict]:
    """Refine every material to a per-material target and render the scene with every
    material sparse; while that misses ``target_snr`` (the errors add up), raise the
    per-material target by the shortfall and refine again (at most 4 rounds)."""
    margin, rounds = 0.0, []
    for _ in range(4):
        goal = target_snr + margin
        for mid, fit in fits.items():
            i = fit.chosen
            while _verify(mid, fit, i, scn, out) < goal and i + 1 < len(fit.candidates):
                i += 1
            while i > 0 and _verify(mid, fit, i - 1, scn, out) >= goal:
                i -= 1
            fit.chosen = i
        files = {mid: str(save_sbrdf(out / f"{mid}.sbrdf", fit.candidates[fit.chosen]))
                 for mid, fit in fits.items()}
        forms = scn.snr(files)
        scene_snr = forms.object
        rounds.append({"per_material_target": goal, "scene_snr": scene_snr,
                       "scene_snr_whole": forms.whole})
        if progress:
            print(f"  per-material target {goal:.1f} dB -> scene {OBJECT_ONLY} "
                  f"{scene_snr:.1f} dB ({WHOLE_IMAGE} {forms.whole:.1f} dB)")
        if scene_snr >= target_snr or all(fit.at_top for fit in fits.values()):
            break
        margin += target_snr - scene_snr + 0.5
    return rounds


def _material_row(mid: str, fit: _Fit, source: str, out: Path, ens: Ensemble,
                  ladder: Sequence[int], progress: bool) -> dict:
    """The report row of one material (its final file written by the last round)."""
    i, model = fit.chosen, fit.candidates[fit.chosen]
    (out / f"{mid}.candidate.sbrdf").unlink(missing_ok=True)
    final = out / f"{mid}.sbrdf"
    strict = sum(strict_channel(*channel_terms(model, ens, c)).nbytes for c in range(3))
    row = {
        "id": mid, "source": str(source), "coefficients": int(ladder[i]),
        "transform": model.transform, "file": str(final),
        "bytes": final.stat().st_size, "predicted_snr": fit.predicted[i],
        "verified_snr": fit.verified[i].object, "verified_snr_whole": fit.verified[i].whole,
        "renders": len(fit.verified), "memory_strict": int(strict),
        "memory_grouped": grouped_bytes(model, ens),
        "memory_tabulated": int(np.prod(fit.brdf.shape)) * 3 * 4,
    }
    if progress:
        print(f"  {mid}: {row['coefficients']} coefficients/channel, predicted "
              f"{row['predicted_snr']:.1f} dB, verified alone {OBJECT_ONLY} "
              f"{row['verified_snr']:.1f} dB ({WHOLE_IMAGE} {row['verified_snr_whole']:.1f}"
              f" dB; {row['renders']} renders)")
    return row


def _write(rep: dict, out: Path) -> None:
    with atomic_write(out / "fit-scene.json", "w") as f:
        json.dump(rep, f, indent=1)
    lines = [
        f"# fit-scene: {rep['scene']} at {rep['target_snr']:.1f} dB", "",
        f"Verification renders: {rep['res']}x{rep['res']}, {rep['spp']} spp, seed "
        f"{rep['seed']}; proxy offset {rep['offset_db']:+.1f} dB. SNRs target the "
        f"{OBJECT_ONLY} form (pixels whose camera rays hit geometry); the {WHOLE_IMAGE} form "
        "(every pixel) is given beside it.", "",
        "| material | coefficients/channel | transform | bytes | predicted SNR | verified SNR "
        f"{OBJECT_ONLY} (this material sparse) | {WHOLE_IMAGE} | "
        "memory strict | memory grouped |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rep["materials"]:
        lines.append(f"| {r['id']} | {r['coefficients']} | {r['transform']} | {r['bytes']} | "
                     f"{r['predicted_snr']:.1f} | {r['verified_snr']:.1f} | "
                     f"{r['verified_snr_whole']:.1f} | {r['memory_strict']} | "
                     f"{r['memory_grouped']} |")
    mem = rep["memory_strict_total"] / rep["memory_tabulated_total"]
    lines += [""] + [f"Round {k + 1}: per-material target {r['per_material_target']:.1f} dB, "
                     f"scene with every material sparse {OBJECT_ONLY} {r['scene_snr']:.1f} dB, "
                     f"{WHOLE_IMAGE} {r['scene_snr_whole']:.1f} dB."
                     for k, r in enumerate(rep["rounds"])]
    lines += [
        "", f"Scene with every material sparse: {OBJECT_ONLY} "
            f"{rep['scene_snr_all_sparse']:.1f} dB, {WHOLE_IMAGE} "
            f"{rep['scene_snr_all_sparse_whole']:.1f} dB.",
        f"Files: {rep['bytes_total']} bytes, against {rep['bytes_fixed_262']} at a fixed "
        f"{DEFAULT_N_COEFFS} coefficients and {rep['bytes_tabulated_merl']} as MERL files.",
        f"Memory (strict decoder, atoms used only): {rep['memory_strict_total']} bytes, "
        f"{100 * mem:.2f} % of the tabulated materials' {rep['memory_tabulated_total']}.",
        f"Took {rep['seconds']:.0f} s."]
    with atomic_write(out / "fit-scene.md", "w") as f:
        f.write("\n".join(lines) + "\n")
