"""The main job (``make demo``): the shipped ensemble on unseen materials, end to end.

Runs on the embedded default: the shipped ensemble, the shipped sphere scene and the
built-in ``mitsuba`` corpus's test split (plus the first shared MERL/RGL test materials
when ``../shared/data`` is present). Into ``demo_out/`` (or ``--out``):

1. encode every material (262 coefficients per channel), write its ``.sbrdf``, decode
   and measure in BRDF space; ``report.md`` and ``demo.png``;
2. render the sphere with the model and with the full tabulated reference (same seed
   and sampling), print the rendering SNR beside the noise floor;
3. run the bench of ``benchmarks/demo.toml`` (baselines side by side, the speed-vs-
   accuracy chart, the stability table) into ``demo_out/bench/report.md``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from .corpora import get_corpus, shared_data_dir
from .encode import DEFAULT_N_COEFFS, encode
from .ensemble import Ensemble
from .merl import write_merl
from .metrics import cosine_weighted_snr, rae
from .sbrdf import save_sbrdf


def _materials(include_shared: bool, per_corpus: int | None):
    mats = get_corpus("mitsuba").split("test")
    if include_shared and shared_data_dir() is not None:
        for name in ("merl", "rgl"):
            mats += get_corpus(name).split("test")[:per_corpus]
    return mats


def _figure(rows, examples, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(12, 3.2 * (1 + len(examples))), constrained_layout=True)
    gs = fig.add_gridspec(1 + len(examples), 3)
    ax = fig.add_subplot(gs[0, :])
    names = [r["material"] for r in rows]
    ax.bar(range(len(rows)), [r["cos_snr_db"] for r in rows],
           color=["C0" if r["transform"] == "log-plus" else "C1" for r in rows])
    ax.set_xticks(range(len(rows)), names, rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("cosine-weighted SNR (dB)")
    ax.set_title(f"Unseen materials at {DEFAULT_N_COEFFS} coefficients per channel "
                 "(blue: log-plus, orange: log-plus-cosine)")
    for row, (name, ref, rec) in enumerate(examples, start=1):
        k = ref.shape[2] // 2  # phi_d = 90 degrees
        lo = max(1e-4, float(np.percentile(ref[..., k, 1][ref[..., k, 1] > 0], 1)))
        hi = float(ref[..., k, 1].max())
        for col, (img, title) in enumerate(((ref, "reference"), (rec, "sparse model"))):
            a = fig.add_subplot(gs[row, col])
            a.imshow(np.log10(np.clip(img[..., k, 1], lo, None)), origin="lower",
                     vmin=np.log10(lo), vmax=np.log10(hi), aspect="auto", cmap="magma")
            a.set_title(f"{name}: {title}, log10 rho (G), phi_d = 90 deg", fontsize=8)
            a.set_xlabel("theta_d bin")
            a.set_ylabel("theta_h bin")
        a = fig.add_subplot(gs[row, 2])
        err = np.abs(ref[..., k, 1] - rec[..., k, 1]) / np.maximum(ref[..., k, 1], lo)
        im = a.imshow(err, origin="lower", vmin=0, vmax=0.5, aspect="auto", cmap="jet")
        a.set_title("relative error", fontsize=8)
        fig.colorbar(im, ax=a)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def run(out: Path, include_shared: bool = True, per_corpus: int | None = 4) -> list[dict]:
    """Encode, decode and measure; write files into ``out``; return one row per material."""
    out.mkdir(parents=True, exist_ok=True)
    ens = Ensemble.default()
    print(f"ensemble: {ens.n_dicts} dictionaries, id {ens.id}")
    rows, examples = [], []
    for m in _materials(include_shared, per_corpus):
        t0 = time.perf_counter()
        brdf = m.load()
        t1 = time.perf_counter()
        model = encode(brdf, ens, DEFAULT_N_COEFFS)
        t2 = time.perf_counter()
        path = save_sbrdf(out / f"{m.corpus}-{m.name}.sbrdf", model)
        rec = model.decode(ens, valid=brdf.valid)
        row = {
            "corpus": m.corpus, "material": m.name, "transform": model.transform,
            "coefficients": int(model.n_coeffs.sum()), "bytes": path.stat().st_size,
            "rae": rae(brdf.values, rec.values, brdf.valid),
            "cos_snr_db": cosine_weighted_snr(brdf.values, rec.values, brdf.valid),
            "load_s": t1 - t0, "encode_s": t2 - t1,
        }
        rows.append(row)
        print(f"  {m.corpus:8s} {m.name:34s} {model.transform:16s} RAE {row['rae']:.4f}  "
              f"SNR {row['cos_snr_db']:5.1f} dB  {row['bytes']} bytes  "
              f"encode {row['encode_s']:.2f} s")
        if len(examples) < 2 and m.corpus in ("merl", "mitsuba"):
            examples.append((m.name, brdf.values, rec.values))
        if len(rows) == 1:
            write_merl(out / f"{m.name}-decoded.binary", rec)
    _figure(rows, examples, out / "demo.png")
    (out / "results.json").write_text(json.dumps(rows, indent=2))
    mean = float(np.mean([r["cos_snr_db"] for r in rows]))
    lines = [
        "# sparse-brdf demo", "",
        f"Ensemble `{ens.id}` ({ens.n_dicts} dictionaries); {DEFAULT_N_COEFFS} coefficients "
        "per channel; unseen (test-split) materials.", "",
        "| corpus | material | transform | RAE | cos-weighted SNR (dB) | bytes | encode (s) |",
        "|---|---|---|---|---|---|---|",
    ] + [f"| {r['corpus']} | {r['material']} | {r['transform']} | {r['rae']:.4f} | "
         f"{r['cos_snr_db']:.1f} | {r['bytes']} | {r['encode_s']:.2f} |" for r in rows] + [
        "", f"Mean cosine-weighted SNR: {mean:.1f} dB", "", "![demo](demo.png)", ""]
    (out / "report.md").write_text("\n".join(lines))
    print(f"mean cosine-weighted SNR {mean:.1f} dB over {len(rows)} materials")
    print(f"wrote {out / 'report.md'}, {out / 'demo.png'}, {len(rows)} .sbrdf files")
    return rows


def render_pair(out: Path, material: str, sbrdf: Path, spp: int = 32, res: int = 128) -> dict:
    """Render the sphere with the model and the reference; SNR and noise floor."""
    from .bench import SCENES_DIR
    from .metrics import render_snr
    from .render import render_scene, write_exr

    scene = SCENES_DIR / "sphere.xml"
    times = {}
    imgs = {}
    for tag, src, seed in (("reference", material, 0), ("reference-seed1", material, 1),
                           ("model", str(sbrdf), 0)):
        t0 = time.perf_counter()
        imgs[tag] = render_scene(scene, {"material": src}, spp=spp, seed=seed, res=res)
        times[tag] = time.perf_counter() - t0
        write_exr(out / f"sphere-{tag}.exr", imgs[tag])
    snr = render_snr(imgs["reference"], imgs["model"])
    floor = render_snr(imgs["reference"], imgs["reference-seed1"])
    print(f"sphere ({res}x{res}, {spp} spp): model vs reference {snr:.1f} dB "
          f"(noise floor {floor:.1f} dB); wall time of one call each (scene load, JIT "
          f"compile when new, render): {times['model']:.2f} s model, "
          f"{times['reference']:.2f} s reference; render speed without these: "
          f"docs/benchmarks.md")
    return {"snr_db": snr, "noise_floor_db": floor, "seconds": times}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sparse_brdf.demo", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="demo_out", help="output folder")
    p.add_argument("--builtin-only", action="store_true",
                   help="only the built-in corpus, even when ../shared/data is present")
    p.add_argument("--no-bench", action="store_true", help="skip step 3 (the bench)")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    out = Path(args.out)
    print("== 1. encode unseen materials with the shipped ensemble")
    rows = run(out, include_shared=not args.builtin_only)
    print("== 2. render the sphere: sparse model against the tabulated reference")
    first = rows[0]
    src = f"mitsuba:{first['material']}" if first["corpus"] == "mitsuba" else None
    if src is None:
        src = str(get_corpus(first["corpus"]).split("test")[0].source)
    pair = render_pair(out, src, out / f"{first['corpus']}-{first['material']}.sbrdf")
    (out / "sphere.json").write_text(json.dumps(pair, indent=2))
    if not args.no_bench:
        print("== 3. bench: baselines, speed-vs-accuracy chart, stability "
              "(benchmarks/demo.toml)")
        from .bench import Bench, BenchConfig

        cfg = BenchConfig.load(Path(__file__).resolve().parent.parent / "benchmarks"
                               / "demo.toml")
        cfg.out = str(out / "bench")
        Bench(cfg).run()
        print(f"wrote {cfg.out}/report.md (tables, speed_accuracy.png, renders)")
    print(f"demo finished in {time.perf_counter() - t0:.0f} s; open {out}/report.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
