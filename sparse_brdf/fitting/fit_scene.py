"""Model no more than a scene needs: per-material coefficient budgets for a target SNR.

For every measured material of a scene, :func:`fit_scene`

1. *predicts* the fewest coefficients per channel (from a ladder 16, 32, ..., 4096; the
   default encoder, so 3 x that many per material over the opponent channels) whose
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
import math
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..coding.budget import encode_to_bytes
from ..coding.coefficients import SparseBRDF
from ..coding.encode import encode
from ..coding.ensemble import Ensemble, resolve_ensemble
from ..coding.fileformat import save_sbrdf, to_bytes
from ..coding.spec import DEFAULT_N_COEFFS
from ..decoders.layouts import channel_terms, grouped_bytes, strict_channel
from ..errors import OutputError, UsageError
from ..evaluation.render import SHARED_PATHS, object_mask, render_scene
from ..evaluation.scenes import parse_scene
from ..fileio import atomic_write, check_output
from ..metrics import OBJECT_ONLY, WHOLE_IMAGE, SNRForms, cosine_weighted_snr, snr_forms
from ..paths import CALIBRATION_PATH
from ..sources.load import load_brdf

LADDER: tuple[int, ...] = (16, 32, 64, 128, 262, 512, 1024, 2048, 4096)


def calibration_offset() -> float:
    """dB to add to the cosine-weighted BRDF SNR to predict the rendering SNR."""
    if CALIBRATION_PATH.is_file():
        return float(json.loads(CALIBRATION_PATH.read_text())["offset_db"])
    return 0.0


def scene_materials(scene: str | os.PathLike, overrides: Mapping[str, str]) -> dict[str, str]:
    """Measured materials of a scene: ``tabulated_brdf``/``sparse_brdf`` BSDFs with a
    ``filename`` in the XML (by id), then ``overrides`` (id -> source) on top."""
    root = parse_scene(scene).getroot()
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
        raise UsageError(f"{scene}: no measured materials: give them with --material ID=FILE")
    return found


class _Ladder:
    """One material's candidate models along the ladder of budgets (coefficients per
    channel), encoded with the default encoder on first use, and their predicted SNRs
    (cosine-weighted SNR + the calibration offset). Most rungs are never encoded: the
    starting rung is found by bisection (the prediction rises with the budget) and the
    refinement visits its neighbours. With ``max_bytes`` the ladder ends at the largest
    encoding whose file fits (:func:`~sparse_brdf.coding.budget.encode_to_bytes`)."""

    def __init__(self, brdf: BRDF, ens: Ensemble, counts: Sequence[int], offset: float,
                 max_bytes: int | None = None):
        self.brdf, self.ens, self.offset = brdf, ens, offset
        self.counts: list[int | None] = list(counts)
        self._models: dict[int, SparseBRDF] = {}
        self._pred: dict[int, float] = {}
        if max_bytes is not None:
            top = encode_to_bytes(brdf, ens, max_bytes)
            n_top = -(-int(top.n_coeffs.sum()) // 3)  # per channel, as the ladder counts
            self.counts = [n for n in self.counts if n < n_top] + [None]
            self._add(len(self.counts) - 1, top)

    def __len__(self) -> int:
        return len(self.counts)

    def __getitem__(self, k: int) -> SparseBRDF:
        if k not in self._models:
            self._add(k, encode(self.brdf, self.ens, self.counts[k]))
        return self._models[k]

    def _add(self, k: int, model: SparseBRDF) -> None:
        rec = model.decode(self.ens, valid=self.brdf.valid).values
        self._models[k] = model
        self._pred[k] = cosine_weighted_snr(self.brdf.values, rec, self.brdf.valid) + self.offset

    def predicted(self, k: int) -> float:
        """Predicted object-only rendering SNR (dB) of rung ``k``."""
        self[k]
        return self._pred[k]

    def first_reaching(self, target: float) -> int:
        """The lowest rung predicted to reach ``target`` dB (the top one if none does)."""
        lo, hi = 0, len(self) - 1
        while lo < hi:
            mid = (lo + hi) // 2
            lo, hi = (lo, mid) if self.predicted(mid) >= target else (mid + 1, hi)
        return lo


@dataclass
class _Fit:
    """One material's state: its candidate models along the ladder, their predicted SNRs,
    the SNRs verified so far and the ladder index currently chosen."""

    brdf: BRDF
    candidates: _Ladder
    chosen: int
    verified: dict[int, SNRForms] = field(default_factory=dict)  # ladder index -> SNRs
    bytes_default: int = 0  # its file at DEFAULT_N_COEFFS per channel

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
                            sparse_options=self.sparse_options, sampling=SHARED_PATHS)

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
    max_bytes: int | None = None,
) -> dict:
    """Fit every measured material of ``scene`` to ``target_snr`` dB; see module doc.
    ``max_bytes``: no material's file holds more (``--bytes``, per material)."""
    if not math.isfinite(target_snr):
        raise UsageError(f"target SNR must be a finite number of dB, got {target_snr}")
    ens = ensemble or resolve_ensemble(ensemble_path)
    out = Path(out)
    mats = scene_materials(scene, overrides or {})
    _check_out(out, [scene, ensemble_path, *mats.values()], list(mats))
    offset = calibration_offset()
    opts = {"ensemble": ensemble_path} if ensemble_path else None
    t0 = time.perf_counter()
    scn = _Scene(scene, mats, spp, res, seed, opts)
    scn.reference = scn.render(mats)
    scn.mask = object_mask(scene, res=res, materials=list(mats))
    fits = {}
    for mid, src in mats.items():
        brdf = load_brdf(src)
        cands = _Ladder(brdf, ens, ladder, offset, max_bytes)
        fixed = len(to_bytes(cands[cands.counts.index(DEFAULT_N_COEFFS)]
                             if DEFAULT_N_COEFFS in cands.counts
                             else encode(brdf, ens, DEFAULT_N_COEFFS)))
        fits[mid] = _Fit(brdf, cands, cands.first_reaching(target_snr), bytes_default=fixed)
    try:
        rounds = _fit_rounds(fits, scn, out, target_snr, progress)
    except BaseException:  # interrupted or failed: no candidate file is left behind
        for mid in fits:
            (out / f"{mid}.candidate.sbrdf").unlink(missing_ok=True)
        raise
    rows = [_material_row(mid, fit, mats[mid], out, ens, ladder, progress)
            for mid, fit in fits.items()]
    report = {
        "scene": str(scene), "target_snr": target_snr, "offset_db": offset, "spp": spp,
        "res": res, "size": [int(scn.reference.shape[1]), int(scn.reference.shape[0])],
        "seed": seed, "materials": rows,
        "scene_snr_all_sparse": rounds[-1]["scene_snr"],
        "scene_snr_all_sparse_whole": rounds[-1]["scene_snr_whole"], "rounds": rounds,
        "bytes_total": sum(r["bytes"] for r in rows), "bytes_cap": max_bytes,
        # the key keeps its name (262 = DEFAULT_N_COEFFS) for readers of earlier reports;
        # the same file version as the fitted files
        "bytes_fixed_262": sum(fit.bytes_default for fit in fits.values()),
        "bytes_tabulated_merl": len(rows) * (12 + 8 * 3 * int(np.prod(ens.shape))),
        "memory_strict_total": sum(r["memory_strict"] for r in rows),
        "memory_tabulated_total": sum(r["memory_tabulated"] for r in rows),
        "seconds": time.perf_counter() - t0,
    }
    _write(report, out)
    return report


def _check_out(out: Path, inputs: list, ids: list[str]) -> None:
    """Create the output folder, refusing one that is a file or whose outputs would
    overwrite an input."""
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder: fit-scene writes a folder")
    for i in ids:  # ids name files in the folder: none may point elsewhere
        if not i or "/" in i or "\\" in i or i in (".", ".."):
            raise UsageError(f"material id {i!r}: not usable as a file name in {out}")
    for name in ["fit-scene.json", "fit-scene.md"] + [f"{i}{s}" for i in ids
                                                        for s in (".sbrdf", ".candidate.sbrdf")]:
        check_output(out / name, inputs)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{out}: cannot create the output folder: {exc.strerror}") from exc


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
        "id": mid, "source": str(source),
        # the rung's budget per channel (the byte-capped top rung: its total / 3)
        "coefficients": int(fit.candidates.counts[i] or -(-int(model.n_coeffs.sum()) // 3)),
        "coefficients_total": int(model.n_coeffs.sum()),
        "transform": model.transform, "file": str(final),
        "bytes": final.stat().st_size, "predicted_snr": fit.candidates.predicted(i),
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
        f"Verification renders: {rep['size'][0]}x{rep['size'][1]}, {rep['spp']} spp, seed "
        f"{rep['seed']}; proxy offset {rep['offset_db']:+.1f} dB. SNRs target the "
        f"{OBJECT_ONLY} form (pixels whose camera rays first hit a shape of the fitted "
        f"materials); the {WHOLE_IMAGE} form "
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
        f"{DEFAULT_N_COEFFS} coefficients and {rep['bytes_tabulated_merl']} as MERL files"
        + (f"; at most {rep['bytes_cap']} bytes per file (--bytes)." if rep.get("bytes_cap")
           else "."),
        f"Memory (strict decoder, atoms used only): {rep['memory_strict_total']} bytes, "
        f"{100 * mem:.2f} % of the tabulated materials' {rep['memory_tabulated_total']}.",
        f"Took {rep['seconds']:.0f} s."]
    with atomic_write(out / "fit-scene.md", "w") as f:
        f.write("\n".join(lines) + "\n")
