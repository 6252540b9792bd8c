"""The noise of the plugins' two BSDF sampling modes at equal spp, in scenes lit by a light
source (``docs/rendering.md``, "Which sampling when"; ``docs/benchmarks.md``).

    .venv/bin/python benchmarks/sampling_noise.py --json docs/figures/sampling_noise.json

For each scene and material, ``--seeds`` renders at ``--spp`` with ``cosine`` and with
``lobe`` sampling are compared with a reference (the mean of ``--ref-renders`` lobe
renders at ``--ref-spp``, other seeds): the SNR (dB) of each render against the
reference in both forms (object-only: the shapes of the material; whole-image), averaged
over the seeds, the largest pixel value (fireflies), and the seconds per render. Scenes:
``sphere_light`` (the studio sphere under one distant light) and the still life of the
tests (``tests/data/still_life.xml``: a small area light, a cube and a sphere of the
material on a ground plane, path tracing to depth 3).
"""

from __future__ import annotations

import time

import numpy as np
from harness import ROOT, header, parser, write_json

from sparse_brdf.evaluation.render import object_mask, render_scene
from sparse_brdf.metrics import snr_forms
from sparse_brdf.paths import DEMO_MATERIALS_DIR

#: (scene, the id of the material replaced, its resolution).
SCENES = (("sphere", "material", 96),
          (str(ROOT / "tests" / "data" / "still_life.xml"), "paint", 96))
MATERIALS = ("mitsuba:au-ggx-0.08", str(DEMO_MATERIALS_DIR / "blue-metallic-paint2.h5"),
             "mitsuba:diffuse-white")


def measure(scene: str, mid: str, res: int, material: str, args) -> list[dict]:
    mats = {mid: material}
    refs = [render_scene(scene, mats, spp=args.ref_spp, seed=1000 + i, res=res,
                         sampling="lobe") for i in range(args.ref_renders)]
    ref = np.mean(refs, axis=0)
    mask = object_mask(scene, res=(ref.shape[1], ref.shape[0]), materials=[mid])
    rows = []
    for sampling in ("cosine", "lobe"):
        snr, peak, secs = [], [], []
        for seed in range(args.seeds):
            t0 = time.perf_counter()
            img = render_scene(scene, mats, spp=args.spp, seed=seed, res=res,
                               sampling=sampling)
            secs.append(time.perf_counter() - t0)
            snr.append(snr_forms(ref, img, mask))
            peak.append(float(img.max()))
        rows.append({"scene": scene.rsplit("/", 1)[-1], "material": material.rsplit("/", 1)[-1],
                     "sampling": sampling, "spp": args.spp, "seeds": args.seeds,
                     "snr_object_db": float(np.mean([s.object for s in snr])),
                     "snr_whole_db": float(np.mean([s.whole for s in snr])),
                     "max_pixel": float(np.max(peak)), "reference_max": float(ref.max()),
                     "seconds": float(np.median(secs))})
    return rows


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--spp", type=int, default=16, help="spp of the compared renders")
    p.add_argument("--seeds", type=int, default=8, help="renders per sampling mode")
    p.add_argument("--ref-spp", type=int, default=1024, help="spp of each reference render")
    p.add_argument("--ref-renders", type=int, default=4, help="renders averaged into the "
                                                              "reference")
    p.add_argument("--res", type=int, default=None, help="resolution of every scene "
                   "(default: each scene's own, 96)")
    p.add_argument("--materials", nargs="+", default=list(MATERIALS), help="BRDF sources")
    p.add_argument("--scenes", nargs="+", choices=[s[0].rsplit("/", 1)[-1] for s in SCENES],
                   default=[s[0].rsplit("/", 1)[-1] for s in SCENES])
    args = p.parse_args()
    rows = []
    for scene, mid, res in SCENES:
        if scene.rsplit("/", 1)[-1] not in args.scenes:
            continue
        for material in args.materials:
            rows += measure(scene, mid, args.res or res, material, args)
    print(header())
    print(f"SNR against a {args.ref_renders} x {args.ref_spp} spp reference, mean of "
          f"{args.seeds} seeds at {args.spp} spp\n")
    print("| scene | material | sampling | object-only dB | whole-image dB | max pixel "
          "(reference) | s/render |")
    print("|---|---|---|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['scene']} | {r['material']} | {r['sampling']} | "
              f"{r['snr_object_db']:.1f} | {r['snr_whole_db']:.1f} | {r['max_pixel']:.2f} "
              f"({r['reference_max']:.2f}) | {r['seconds']:.2f} |")
    if args.json:
        write_json(args.json, rows, args)


if __name__ == "__main__":
    main()
