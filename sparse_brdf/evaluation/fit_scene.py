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
from pathlib import Path

import numpy as np

from ..fileio import atomic_write
from ..metrics import OBJECT_ONLY, WHOLE_IMAGE, cosine_weighted_snr, snr_forms
from ..model.encode import choose_transform, project_all, select
from ..model.ensemble import Ensemble
from ..model.sbrdf import file_size, save_sbrdf
from ..paths import CALIBRATION_PATH
from ..sources.load import load_brdf
from ..transforms import TRANSFORMS

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
    from mitsuba_plugin.data import channel_terms, grouped_bytes, strict_channel

    from .render import object_mask, render_scene

    ens = ensemble or (Ensemble.load(ensemble_path) if ensemble_path else Ensemble.default())
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    mats = scene_materials(scene, overrides or {})
    offset = calibration_offset()
    opts = {"ensemble": ensemble_path} if ensemble_path else None
    t0 = time.perf_counter()

    def render(materials):
        return render_scene(scene, materials, spp=spp, seed=seed, res=res, sparse_options=opts)

    reference = render(mats)
    mask = object_mask(scene, res=res)
    fitted = {}  # id -> (brdf, candidates, predictions, verified SNRs, chosen index)
    for mid, src in mats.items():
        brdf = load_brdf(src)
        cands, preds, i = _predict(brdf, ens, list(ladder), target_snr, offset)
        fitted[mid] = [brdf, cands, preds, {}, i]

    def verify(mid, k):
        _, cands, _, verified, _ = fitted[mid]
        if k not in verified:
            path = save_sbrdf(out / f"{mid}.candidate.sbrdf", cands[k])
            verified[k] = snr_forms(reference, render({**mats, mid: str(path)}), mask)
        return verified[k].object

    # Per-material targets start at the scene target; while the scene with every
    # material sparse misses it (the errors add up), they are raised by the shortfall.
    margin, rounds = 0.0, []
    for _ in range(4):
        goal = target_snr + margin
        for mid, f in fitted.items():
            i = f[4]
            while verify(mid, i) < goal and i + 1 < len(f[1]):
                i += 1
            while i > 0 and verify(mid, i - 1) >= goal:
                i -= 1
            f[4] = i
        files = {mid: str(save_sbrdf(out / f"{mid}.sbrdf", f[1][f[4]]))
                 for mid, f in fitted.items()}
        forms = snr_forms(reference, render({**mats, **files}), mask)
        scene_snr = forms.object
        rounds.append({"per_material_target": goal, "scene_snr": scene_snr,
                       "scene_snr_whole": forms.whole})
        if progress:
            print(f"  per-material target {goal:.1f} dB -> scene {OBJECT_ONLY} "
                  f"{scene_snr:.1f} dB ({WHOLE_IMAGE} {forms.whole:.1f} dB)")
        if scene_snr >= target_snr or all(f[4] == len(f[1]) - 1 for f in fitted.values()):
            break
        margin += target_snr - scene_snr + 0.5
    rows = []
    for mid, (brdf, cands, preds, verified, i) in fitted.items():
        model = cands[i]
        (out / f"{mid}.candidate.sbrdf").unlink(missing_ok=True)
        final = out / f"{mid}.sbrdf"
        strict = sum(strict_channel(*channel_terms(model, ens, c)).nbytes for c in range(3))
        row = {
            "id": mid, "source": str(mats[mid]), "coefficients": int(ladder[i]),
            "transform": model.transform, "file": str(final),
            "bytes": final.stat().st_size, "predicted_snr": preds[i],
            "verified_snr": verified[i].object, "verified_snr_whole": verified[i].whole,
            "renders": len(verified), "memory_strict": int(strict),
            "memory_grouped": grouped_bytes(model, ens),
            "memory_tabulated": int(np.prod(brdf.shape)) * 3 * 4,
        }
        rows.append(row)
        if progress:
            print(f"  {mid}: {row['coefficients']} coefficients/channel, predicted "
                  f"{row['predicted_snr']:.1f} dB, verified alone {OBJECT_ONLY} "
                  f"{row['verified_snr']:.1f} dB ({WHOLE_IMAGE} {row['verified_snr_whole']:.1f}"
                  f" dB; {row['renders']} renders)")
    report = {
        "scene": str(scene), "target_snr": target_snr, "offset_db": offset, "spp": spp,
        "res": res, "seed": seed, "materials": rows,
        "scene_snr_all_sparse": rounds[-1]["scene_snr"],
        "scene_snr_all_sparse_whole": rounds[-1]["scene_snr_whole"], "rounds": rounds,
        "bytes_total": sum(r["bytes"] for r in rows),
        "bytes_fixed_262": sum(file_size(3 * 262, len(r["id"])) for r in rows),
        "bytes_tabulated_merl": len(rows) * (12 + 8 * 3 * int(np.prod(ens.shape))),
        "memory_strict_total": sum(r["memory_strict"] for r in rows),
        "memory_tabulated_total": sum(r["memory_tabulated"] for r in rows),
        "seconds": time.perf_counter() - t0,
    }
    _write(report, out)
    return report


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
        f"Files: {rep['bytes_total']} bytes, against {rep['bytes_fixed_262']} at a fixed 262 "
        f"coefficients and {rep['bytes_tabulated_merl']} as MERL files.",
        f"Memory (strict decoder, atoms used only): {rep['memory_strict_total']} bytes, "
        f"{100 * mem:.2f} % of the tabulated materials' {rep['memory_tabulated_total']}.",
        f"Took {rep['seconds']:.0f} s."]
    with atomic_write(out / "fit-scene.md", "w") as f:
        f.write("\n".join(lines) + "\n")
