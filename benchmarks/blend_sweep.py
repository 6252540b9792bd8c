"""A blend sweep rendered on the sphere: interpolation in coefficient space
(``docs/fit-scene.md``).

    .venv/bin/python benchmarks/blend_sweep.py A B --out docs/figures/blend.png

A and B are BRDF sources (default: two built-in materials); both are encoded with the
same transform at 262 coefficients, blended at alpha = 0, 0.25, 0.5, 0.75, 1, and
rendered with the sparse_brdf plugin.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from harness import parser

from sparse_brdf.coding.encode import encode
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.fileformat import save_sbrdf
from sparse_brdf.coding.interpolate import interpolate
from sparse_brdf.evaluation.render import render_scene
from sparse_brdf.paths import SCENES_DIR
from sparse_brdf.sources.load import load_brdf


def main() -> None:
    p = parser(__doc__, json_option=False)
    p.add_argument("a", nargs="?", default="mitsuba:au-ggx-0.25")
    p.add_argument("b", nargs="?", default="mitsuba:plastic-blue-ggx-0.2")
    p.add_argument("--transform", default="log-plus-cosine")
    p.add_argument("--alphas", nargs="+", type=float, default=[0, 0.25, 0.5, 0.75, 1])
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--res", type=int, default=160)
    p.add_argument("--out", default="docs/figures/blend.png")
    args = p.parse_args()
    ens = Ensemble.default()
    a = encode(load_brdf(args.a), ens, 262, transform=args.transform)
    b = encode(load_brdf(args.b), ens, 262, transform=args.transform)
    tmp = Path(tempfile.mkdtemp())
    imgs = []
    for alpha in args.alphas:
        f = save_sbrdf(tmp / f"blend-{alpha:g}.sbrdf", interpolate(a, b, alpha, ens))
        imgs.append(render_scene(SCENES_DIR / "sphere.xml", {"material": str(f)},
                                 spp=args.spp, seed=0, res=args.res,
                                 sparse_options={"sampling": "lobe"}))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(imgs), figsize=(2.4 * len(imgs), 2.7),
                             constrained_layout=True)
    for ax, img, alpha in zip(axes, imgs, args.alphas, strict=True):
        ax.imshow(np.clip(img / (1 + img), 0, 1) ** (1 / 2.2))
        ax.set_title(f"alpha = {alpha:g}", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"{args.a} -> {args.b}, blended in coefficient space ({args.transform}, "
                 "262 coefficients per channel)", fontsize=9)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
