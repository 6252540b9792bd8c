"""The bench report: tables (paper's Tables 2-4), figures (Figs. 2-4) and the
speed-vs-accuracy charts, written as markdown + PNG from a bench's ``results``.

Every rendering SNR comes in both forms, labelled: whole-image (every pixel, the paper's)
and object-only (the pixels whose camera rays hit the object; the strict one). Also the
flat ``results.csv`` (:func:`write_csv`)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from ..coding.encode import pick_transform
from ..coding.spec import DEFAULT_N_COEFFS
from ..evaluation.images import read_exr
from ..fileio import atomic_path, atomic_write
from ..metrics import OBJECT_ONLY, WHOLE_IMAGE
from ..transforms import TRANSFORMS
from .charts import FORMS, curve_figure, pyplot, speed_accuracy_chart
from .speed import SETTLE
from .stability import stability_markdown


def _number(x) -> float:
    """A recorded figure as a float; nan where none was recorded (None)."""
    return math.nan if x is None else float(x)


def _finite(xs):
    return [x for x in xs if x is not None and math.isfinite(x)]


def _mean_snr(xs: list[float]) -> float:
    """Mean of finite SNRs; inf when every one is +inf (an exact model), else nan."""
    if xs and all(math.isinf(x) and x > 0 for x in xs):
        return math.inf
    f = _finite(xs)
    return float(np.mean(f)) if f else math.nan


def _stats(xs: list[float]) -> dict:
    if xs and all(math.isinf(x) and x > 0 for x in xs):  # identical to the reference
        return {"mean": math.inf, "std": 0.0, "min": math.inf, "max": math.inf}
    f = _finite(xs)
    if not f:
        return {"mean": math.nan, "std": math.nan, "min": math.nan, "max": math.nan}
    return {"mean": float(np.mean(f)), "std": float(np.std(f)), "min": float(np.min(f)),
            "max": float(np.max(f))}


def scenes_of(results: dict) -> list[str]:
    """Scenes rendered in ``results`` (a model's render or the reference's noise floor,
    so a scene where every model failed still has its section), in first-seen order."""
    out: dict[str, None] = dict.fromkeys(results.get("noise_floor") or {})
    for r in results["cells"].values():
        for s in r.get("renders") or {}:
            out[s] = None
    return list(out)


def corpora_of(results: dict) -> list[str]:
    """Corpora of the materials in ``results`` (the part of ``corpus/name`` keys before
    the slash), in first-seen order."""
    return list(dict.fromkeys(r["material"].split("/", 1)[0] for r in results["cells"].values()))


def noise_floor_means(results: dict, scene: str) -> dict[str, float] | None:
    """The noise floor of ``scene`` (two reference renders with different seeds, see
    :func:`sparse_brdf.evaluation.render.noise_floor_snr`), averaged over the materials:
    ``{"snr_object": dB, "snr_whole": dB}``; None when nothing was measured."""
    nf = list(results["noise_floor"].get(scene, {}).values())
    if not nf:
        return None
    return {key: float(np.mean([x[key] for x in nf])) for key, _ in FORMS}


def flat_rows(results: dict) -> list[dict]:
    """One flat row per cell: per-scene SNRs as ``snr_whole@SCENE``/``snr_object@SCENE``."""
    out = []
    for r in results["cells"].values():
        row = {k: v for k, v in r.items() if k != "renders"}
        for scene, vals in (r.get("renders") or {}).items():
            for k, v in vals.items():
                row[f"{k}@{scene}"] = v
        row["evals_per_s"] = results.get("speed", {}).get(r["model"])
        out.append(row)
    return out


def write_csv(results: dict, path: Path) -> None:
    """``results.csv``: :func:`flat_rows`, columns in name order."""
    rows = flat_rows(results)
    keys = sorted({k for r in rows for k in r})
    with atomic_write(path, "w") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)


def summary_table(results: dict, scene: str | None = None,
                  corpus: str | None = None) -> list[dict]:
    """Per model: bytes, speed, RAE, and rendering SNR statistics of both forms in
    ``scene`` (Table 3), over every material or those of ``corpus``; rows sorted by
    object-only mean SNR (cos-weighted SNR without renders), best first, a model without
    that figure (every cell failed) last. A model none of whose cells finished has no
    evaluations per second (nan), whatever was measured."""
    by_model: dict[str, list[dict]] = {}
    for r in results["cells"].values():
        if corpus is None or r["material"].split("/", 1)[0] == corpus:
            by_model.setdefault(r["model"], []).append(r)
    speed, spread = results.get("speed", {}), results.get("speed_spread", {})
    rows = []
    for model, cells in by_model.items():
        ok = [c for c in cells if c.get("status") == "finished"]
        row = {"model": model, "n": len(ok), "failed": len(cells) - len(ok),
               "bytes": float(np.mean([c["bytes"] for c in ok])) if ok else math.nan,
               "rae": float(np.mean([c["rae"] for c in ok])) if ok else math.nan,
               "cos_snr": _mean_snr([c["cos_snr"] for c in ok]),
               "fit_s": float(np.mean([c["fit_s"] for c in ok])) if ok else math.nan,
               "evals_per_s": _number(speed.get(model)) if ok else math.nan,
               "evals_min": _number(spread.get(model, {}).get("min")) if ok else math.nan,
               "evals_max": _number(spread.get(model, {}).get("max")) if ok else math.nan}
        renders = [c["renders"][scene] for c in ok if scene in (c.get("renders") or {})]
        if renders:
            for key, _ in FORMS:
                for stat, v in _stats([x[key] for x in renders]).items():
                    row[f"{key}_{stat}"] = v
            for key in ("snr_object", "snr_whole", "flip"):  # several seeds: the mean's se
                se = [x[f"{key}_se"] for x in renders if f"{key}_se" in x]
                if se:
                    row[f"{key}_se"] = float(np.sqrt(np.sum(np.square(se)))) / len(se)
            flips = _finite([x.get("flip") for x in renders])
            row["flip_mean"] = float(np.mean(flips)) if flips else math.nan
            row["flip_max"] = float(np.max(flips)) if flips else math.nan
            row["render_s"] = float(np.mean([x["render_s"] for x in renders]))
        rows.append(row)
    rows.sort(key=lambda r: nan_last(r.get("snr_object_mean", r["cos_snr"])))
    return rows


def nan_last(value: float, higher: bool = True) -> tuple[bool, float]:
    """A sort key that puts the best ``value`` first (the highest, or the lowest when not
    ``higher``) and a missing one (None or nan: a failed figure) last."""
    missing = value is None or math.isnan(value)
    return (missing, 0.0 if missing else (-value if higher else value))


def tone(img: np.ndarray) -> np.ndarray:
    """A linear render for display: Reinhard's x / (1 + x), then gamma 2.2, in [0, 1]."""
    return np.clip(img / (1 + img), 0, 1) ** (1 / 2.2)


def flip_map_path(out: Path, scene: str, material: str, model: str) -> Path:
    """Where a bench keeps the HDR-FLIP error map of a cell's render (float16 (H, W))."""
    return out / "work" / scene / f"{material.replace('/', '__')}__{model}.flip.npy"


def difference_figure(results: dict, out: Path, scene: str,
                      max_materials: int = 4) -> list[Path]:
    """Renders, false-colour |ref - img| x 10 (jet) and the HDR-FLIP error map (magma,
    0 to 1) per material (Figs. 3, 4)."""
    work = out / "work" / scene
    mats = sorted({r["material"] for r in results["cells"].values()})[:max_materials]
    models = sorted({r["model"] for r in results["cells"].values()})
    paths = []
    plt = pyplot()
    for key in mats:
        stem = key.replace("/", "__")
        ref_p = work / f"{stem}__reference.exr"
        if not ref_p.is_file():
            continue
        ref = read_exr(ref_p)
        shown = [m for m in models if (work / f"{stem}__{m}.exr").is_file()]
        if not shown:  # every model failed on this material: nothing to set beside it
            continue
        fig, axes = plt.subplots(3, len(shown) + 1, figsize=(2.2 * (len(shown) + 1), 7.0),
                                 constrained_layout=True)
        scales = {}  # row -> an image of its colour map, for the colour bar
        axes = np.atleast_2d(axes)
        axes[0, 0].imshow(tone(ref))
        axes[0, 0].set_title("reference", fontsize=8)
        axes[1, 0].axis("off")
        axes[2, 0].axis("off")
        for i, m in enumerate(shown, start=1):
            img = read_exr(work / f"{stem}__{m}.exr")
            r = (results["cells"].get(f"{key}|{m}", {}).get("renders") or {}).get(scene, {})
            axes[0, i].imshow(tone(img))
            axes[0, i].set_title(f"{m}\nobj {r.get('snr_object', math.nan):.1f} / "
                                 f"whole {r.get('snr_whole', math.nan):.1f} dB", fontsize=7)
            diff = np.abs(ref - img).mean(-1) * 10  # linear radiance, as the paper's figures
            scales[1] = axes[1, i].imshow(np.clip(diff, 0, 1), cmap="jet", vmin=0, vmax=1)
            axes[1, i].set_title("|ref - img| x 10", fontsize=7)
            fp = flip_map_path(out, scene, key, m)
            if fp.is_file():
                scales[2] = axes[2, i].imshow(np.load(fp).astype(np.float32), cmap="magma",
                                              vmin=0, vmax=1)
                axes[2, i].set_title(f"HDR-FLIP, mean {_f(r.get('flip'), '.3f')}", fontsize=7)
            else:
                axes[2, i].axis("off")
        for a in axes.ravel():
            a.set_xticks([])
            a.set_yticks([])
        for row, im in scales.items():  # the colour scales, 0 to 1
            label = "|ref - img| x 10" if row == 1 else "HDR-FLIP"
            fig.colorbar(im, ax=axes[row, :], shrink=0.8, label=label).ax.tick_params(
                labelsize=7)
        fig.suptitle(f"{key} in {scene}", fontsize=9)
        p = out / f"renders-{scene}-{stem}.png"
        with atomic_path(p, suffix=".png") as tmp:
            fig.savefig(tmp, dpi=90)
        plt.close(fig)
        paths.append(p)
    return paths


def transform_table(results: dict, scene: str, form: str = "snr_object") -> tuple[list[str],
                                                                                    dict]:
    """Transform choice by gamma-mapped MSE and by plain MSE against the render-SNR-better
    one in ``scene`` and SNR ``form`` (Table 2); needs the forced-transform cells
    sparse-N-TRANSFORM at N = the default budget (else the middle of the curve's counts).
    The gamma-MSE choice is the encoder's own rule (:func:`pick_transform`)."""
    lines, agree = [], {"gamma": 0, "plain": 0, "n": 0}
    for key, c in sorted(results["curves"].items()):
        names = [t for t in TRANSFORMS if t in c]  # the ensemble's two
        if len(names) != 2:
            continue
        first, second = names
        counts = c["counts"]
        i = counts.index(DEFAULT_N_COEFFS) if DEFAULT_N_COEFFS in counts else len(counts) // 2
        snrs = {}
        for t in names:
            cell = results["cells"].get(f"{key}|sparse-{counts[i]}-{t}", {})
            snrs[t] = ((cell.get("renders") or {}).get(scene) or {}).get(form)
        if None in snrs.values():
            continue
        best = first if snrs[first] >= snrs[second] else second
        by_gamma = pick_transform({t: {"gamma_mse": c[t]["gamma_mse"][i]} for t in names})
        by_plain = min(names, key=lambda t: c[t]["mse"][i])
        agree["gamma"] += by_gamma == best
        agree["plain"] += by_plain == best
        agree["n"] += 1
        lines.append(f"| {key} | {snrs[first]:.1f} ({first}) | {snrs[second]:.1f} ({second}) "
                     f"| {best} | {by_gamma} | {by_plain} |")
    return lines, agree


def _f(x: float, fmt: str = ".1f") -> str:
    return format(x, fmt) if x is not None and not (isinstance(x, float) and math.isnan(x)) \
        else "-"


def seeds_sentence(cfg: dict) -> str:
    """What the reports say of a bench rendered at several seeds ("" for one)."""
    n = cfg.get("seeds", 1)
    return "" if n <= 1 else (f" Each cell rendered at {n} seeds: its figures are the mean "
                              "over them ± the standard error of that mean.")


def _pm(row: dict, key: str, se: str | None = None, fmt: str = ".1f") -> str:
    """``row[key]``, with `` ± `` its standard error over the seeds when it has one
    (``row[se]``, default ``KEY_se``)."""
    err = row.get(se or f"{key}_se")
    return _f(row.get(key), fmt) + (f" ± {_f(err, fmt)}" if err is not None else "")


def _speed(row: dict) -> str:
    """A summary row's evaluations per second, the median with the timings' min and max
    in brackets: "failed" for a model none of whose cells finished, "-" where none was
    measured."""
    if row["n"] == 0:
        return "failed"
    spread = (f" ({_f(row['evals_min'], '.3g')} to {_f(row['evals_max'], '.3g')})"
              if math.isfinite(row.get("evals_min", math.nan)) else "")
    return _f(row["evals_per_s"], ".3g") + spread


def speed_settings(results: dict) -> str:
    """How the speeds were measured, as the reports state it: the direction pairs per
    call, the timed calls and the median's settling (or that none was measured)."""
    cfg = results["config"]
    if not cfg.get("speed", True):
        return "evals/s: not measured (speed = false)."
    n = int(cfg.get("speed_evals", 1 << 20))
    pairs = f"2^{n.bit_length() - 1}" if n & (n - 1) == 0 else f"{n:,}"
    counts = [s["repeats"] for s in results.get("speed_spread", {}).values() if s]
    calls = (f"{min(counts)} to {max(counts)} timed calls" if counts and min(counts) !=
             max(counts) else f"{counts[0]} timed calls" if counts else "repeated calls")
    return (f"evals/s: the model's own evaluator on {pairs} random direction pairs per "
            f"call, the median of {calls} (more until one noisy call could not move it by "
            f"more than {SETTLE:.0%}), the slowest and fastest call in brackets.")


def _scene_section(results: dict, out: Path, scene: str) -> list[str]:
    """The report's section of one scene: noise floor, Tables 3, 4 and 2, charts, renders."""
    rows = summary_table(results, scene)
    md = [f"## Scene `{scene}`", "", *_noise_floor_paragraph(results, scene),
          *_model_table(rows, scene, speed_settings(results)),
          *_corpus_table(results, rows, scene)]
    chart = out / f"speed_accuracy-{scene}.png"
    if speed_accuracy_chart(rows, chart, f" in {scene}"):
        md += ["", f"![speed and size against accuracy in {scene}]({chart.name})"]
    md += _material_table(results, scene)
    md += _transform_sections(results, scene)
    figs = difference_figure(results, out, scene)
    if figs:
        md += ["", f"### Renders (Figs. 3, 4), `{scene}`", ""]
        md += [f"![{p.stem}]({p.name})" for p in figs]
    return md + [""]


def _noise_floor_paragraph(results: dict, scene: str) -> list[str]:
    cfg = results["config"]
    nf = noise_floor_means(results, scene)
    if nf is None:
        return []
    return [f"Noise floor (two reference renders, seeds {cfg['seed']} and "
            f"{cfg['noise_seed']}): {OBJECT_ONLY} mean {nf['snr_object']:.1f} dB, "
            f"{WHOLE_IMAGE} mean {nf['snr_whole']:.1f} dB. Model and reference share "
            "seed and sampling, so the noise cancels in the SNRs below.", ""]


def _model_table(rows: list[dict], scene: str, settings: str) -> list[str]:
    """Table 3: rendering SNR statistics per model in ``scene``."""
    md = [f"### Rendering SNR per model (Table 3), `{scene}`", "",
          f"SNR in dB; *obj* = {OBJECT_ONLY} (pixels whose camera rays hit the object), "
          f"*whole* = {WHOLE_IMAGE} (every pixel, background included: the paper's form). "
          f"{settings} FLIP: "
          "HDR-FLIP over the object's pixels, mean and worst material (0 is identical; "
          "lower is better). render (s): mean seconds of a model's render.", "",
          "| model | materials | failed | bytes | evals/s | fit (s) | RAE | cos-SNR | "
          "obj mean | obj std | obj min | obj max | whole mean | whole min | whole max | "
          "FLIP mean | FLIP max | render (s) |",
          "|---" * 18 + "|"]
    for r in rows:
        md.append(
            f"| {r['model']} | {r['n']} | {r['failed']} | {_f(r['bytes'], '.0f')} | "
            f"{_speed(r)} | {_f(r['fit_s'], '.2f')} | {_f(r['rae'], '.4f')} | "
            f"{_f(r['cos_snr'])} | {_pm(r, 'snr_object_mean', 'snr_object_se')} | "
            f"{_f(r.get('snr_object_std'))} | {_f(r.get('snr_object_min'))} | "
            f"{_f(r.get('snr_object_max'))} | {_pm(r, 'snr_whole_mean', 'snr_whole_se')} | "
            f"{_f(r.get('snr_whole_min'))} | {_f(r.get('snr_whole_max'))} | "
            f"{_pm(r, 'flip_mean', 'flip_se', '.3f')} | {_f(r.get('flip_max'), '.3f')} | "
            f"{_f(r.get('render_s'), '.2f')} |")
    return md


def _corpus_table(results: dict, rows: list[dict], scene: str) -> list[str]:
    """Mean (min) SNR per model and corpus, when the results span several corpora."""
    corpora = corpora_of(results)
    if len(corpora) <= 1:
        return []
    md = ["", f"### Per corpus, `{scene}` (the paper's Table 3 is MERL, Table 6 RGL-EPFL)",
          "", "Mean (min) rendering SNR in dB.", "",
          "| model | " + " | ".join(f"{c}: {OBJECT_ONLY} | {c}: {WHOLE_IMAGE}"
                                  for c in corpora) + " |",
          "|---" * (1 + 2 * len(corpora)) + "|"]
    per = {c: {r["model"]: r for r in summary_table(results, scene, c)} for c in corpora}
    for r in rows:
        cols = []
        for c in corpora:
            x = per[c].get(r["model"], {})
            cols += [f"{_f(x.get(f'{k}_mean'))} ({_f(x.get(f'{k}_min'))})"
                     for k in ("snr_object", "snr_whole")]
        md.append(f"| {r['model']} | " + " | ".join(cols) + " |")
    return md


def _material_table(results: dict, scene: str) -> list[str]:
    """Table 4: every cell's SNRs in ``scene``."""
    md = ["", f"### Per material (Table 4), `{scene}`", "",
          "| material | model | SNR obj (dB) | SNR whole (dB) | HDR-FLIP | render (s) | RAE | "
          "status |", "|---" * 8 + "|"]
    for r in sorted(results["cells"].values(), key=lambda r: (r["material"], r["model"])):
        s = (r.get("renders") or {}).get(scene, {})
        md.append(f"| {r['material']} | {r['model']} | {_pm(s, 'snr_object')} | "
                  f"{_pm(s, 'snr_whole')} | {_pm(s, 'flip', fmt='.3f')} | "
                  f"{_f(s.get('render_s'), '.2f')} | {_f(r.get('rae'), '.4f')} | {r['status']}"
                  f"{': ' + _md_text(r['error']) if r.get('error') else ''} |")
    return md


def failed_cells(results: dict) -> list[dict]:
    """The cells that failed, sorted by material then model: each a dict with
    ``material``, ``model`` and ``error`` (the exception's type and message)."""
    return [{"material": c["material"], "model": c["model"],
             "error": c.get("error") or "no error recorded"}
            for c in sorted(results["cells"].values(), key=lambda c: (c["material"], c["model"]))
            if c.get("status") != "finished"]


def _failed_section(results: dict) -> list[str]:
    """Every failed cell with its error; nothing when none failed."""
    failed = failed_cells(results)
    if not failed:
        return []
    md = ["## Failed cells", "",
          f"{len(failed)} of {len(results['cells'])} cells failed; they are left out of "
          "every mean below and run again by the next run of this bench.", "",
          "| material | model | error |", "|---|---|---|"]
    md += [f"| {c['material']} | {c['model']} | {_md_text(c['error'])} |" for c in failed]
    return md + [""]


def provenance_rows(results: dict) -> list[tuple[str, str]]:
    """Where and with what the results were computed, as (what, value) rows: the machine
    and software of the last run, the renderer's versions, the ensemble and file version,
    and each model's source (the package's version and commit, or an outside module's
    file and sha256) with its options. report.md and report.html show the same rows."""
    env, prov = results.get("environment", {}), results.get("provenance", {})
    renderer = prov.get("environment", {})
    rows = [("last run", f"{env.get('date', '-')} on {env.get('platform', '-')} "
                         f"({env.get('cpus', '-')} CPUs), Python {env.get('python', '-')}"),
            ("sparse-brdf", str(env.get("sparse_brdf", "-"))),
            ("Mitsuba, Dr.Jit", f"{renderer.get('mitsuba', '-')}, {renderer.get('drjit', '-')}"),
            ("CPU", str(renderer.get("machine", env.get("machine", "-")))),
            ("ensemble", str(prov.get("ensemble", "-"))),
            (".sbrdf version written", str(prov.get("sbrdf_version", "-")))]
    seen: dict[str, dict] = {}
    for cell in results.get("cells", {}).values():
        if cell.get("provenance") and cell["model"] not in seen:
            seen[cell["model"]] = cell["provenance"]
    for model, cp in sorted(seen.items()):
        src = cp.get("source", {})
        where = (f"{src.get('module')} ({src.get('file')}, sha256 {str(src.get('sha256'))[:16]})"
                 if "module" in src else
                 f"sparse-brdf {src.get('sparse_brdf')}, commit {src.get('commit') or '-'}")
        options = json.dumps(cp.get("options") or {}, sort_keys=True)
        rows.append((f"model {model}", f"{where}; options {options}"))
    return rows


def _md_text(text: str) -> str:
    """``text`` as one Markdown table cell: on one line, its pipes escaped."""
    return " ".join(str(text).split()).replace("|", "\\|")


def _transform_sections(results: dict, scene: str) -> list[str]:
    """Table 2 in each SNR form (only where the forced-transform cells were run)."""
    md = []
    for form, label in FORMS:
        lines, agree = transform_table(results, scene, form)
        if lines:
            md += ["", f"### Transform choice (Table 2), `{scene}`, {label} SNR", "",
                   f"Gamma-mapped MSE picked the render-SNR-better transform for "
                   f"{agree['gamma']} of {agree['n']} materials; plain MSE for "
                   f"{agree['plain']}.", "",
                   "| material | SNR, first | SNR, second | better | gamma-MSE picks "
                   "| MSE picks |", "|---|---|---|---|---|---|",
                   *lines]
    return md


def write_report(results: dict, out: Path) -> Path:
    """results.csv, report.md and its PNGs in ``out``."""
    out = Path(out)
    write_csv(results, out / "results.csv")
    curve_figure(results, out / "error_vs_coeffs.png")
    cfg = results["config"]
    md = ["# sparse-brdf bench report", "",
          f"Corpora {cfg['corpora']} ({cfg['split']} split), {cfg['res']}x{cfg['res']}, "
          f"{cfg['spp']} spp, seed {cfg['seed']}, scenes {', '.join(cfg['scenes'])}."
          + seeds_sentence(cfg), ""]
    for scene, why in results.get("skipped_scenes", {}).items():
        md += [f"Skipped scene `{scene}`: {why}", ""]
    md += _failed_section(results)
    for scene in scenes_of(results):
        md += _scene_section(results, out, scene)
    if not scenes_of(results):
        md += ["## BRDF-space metrics (no renders)", "", speed_settings(results), "",
               "| model | materials | failed | bytes | evals/s | RAE | cos-SNR (dB) |",
               "|---|---|---|---|---|---|---|"]
        for r in summary_table(results):
            md.append(f"| {r['model']} | {r['n']} | {r['failed']} | {_f(r['bytes'], '.0f')} | "
                      f"{_speed(r)} | {_f(r['rae'], '.4f')} | "
                      f"{_f(r['cos_snr'])} |")
    if results.get("stability"):
        md += ["", "## Stability", "",
               f"Perturbations of {results['stability']['material']}; cosine-weighted SNR "
               "against the clean BRDF, or the outcome.", "",
               *stability_markdown(results["stability"]["rows"])]
    md += ["", "## Error against coefficients (Fig. 2)", "",
           "![error vs coefficients](error_vs_coeffs.png)", "",
           "## Environment and provenance", "", "| what | value |", "|---|---|",
           *(f"| {what} | {_md_text(value)} |" for what, value in provenance_rows(results)),
           ""]
    path = out / "report.md"
    with atomic_write(path, "w") as f:
        f.write("\n".join(md) + "\n")
    return path
