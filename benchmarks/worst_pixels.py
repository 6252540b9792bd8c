"""Where an encoding's rendering error sits: the worst pixels of one view of ``sphere.xml``.

    .venv/bin/python benchmarks/worst_pixels.py [--material blue-metallic-paint2]
        [--view envrot=225] [--res 32] [--spp 256] [--count 6]

Renders a shipped demo material from its full table and from its encoding (262 per
channel) with the same seed and spp, and prints the pixels of largest squared error:
their position (row, column, and distance from the sphere's centre as a fraction of its
radius), both renders' values and each pixel's share of the view's squared error.
docs/records/fit-images-runs.md, "Where it stands".
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from harness import header, parser

from sparse_brdf import encode, load_brdf
from sparse_brdf.coding.fileformat import save_sbrdf
from sparse_brdf.evaluation.render import SHARED_PATHS, object_mask, render_scene
from sparse_brdf.evaluation.scenes import find_scene, parse_defaults
from sparse_brdf.paths import DEMO_MATERIALS_DIR
from sparse_brdf.sources.merl import write_merl


def main() -> None:
    p = parser(__doc__, json_option=False)
    p.add_argument("--material", default="blue-metallic-paint2")
    p.add_argument("--view", default="envrot=225",
                   help="the view's scene defaults, K=V[,K=V] (e.g. envrot=225,envtilt=10)")
    p.add_argument("--res", type=int, default=32)
    p.add_argument("--spp", type=int, default=256)
    p.add_argument("--count", type=int, default=6)
    args = p.parse_args()
    print(header())
    tmp = Path(tempfile.mkdtemp(prefix="worst-pixels-"))
    scene = find_scene("sphere.xml")
    mask = object_mask(scene, res=args.res)
    brdf = load_brdf(DEMO_MATERIALS_DIR / f"{args.material}.h5")
    sources = {"table": write_merl(tmp / "m.binary", brdf),
               "encoding": save_sbrdf(tmp / "m.sbrdf", encode(brdf))}
    params = parse_defaults(args.view.split(","), f"view {args.view!r}:")
    img = {k: render_scene(scene, {"material": str(f)}, sampling=SHARED_PATHS,
                           spp=args.spp, res=args.res,
                           params=params) for k, f in sources.items()}
    err = np.sum(np.square(img["encoding"].astype(np.float64) - img["table"]), axis=-1)
    ys, xs = np.nonzero(mask)
    cy, cx, radius = ys.mean(), xs.mean(), np.sqrt(mask.sum() / np.pi)
    print(f"{args.material}, {args.view}, {args.res}x{args.res}, {args.spp} spp; object "
          f"mean {img['table'][mask].mean(axis=0).round(4)}")
    for i in np.argsort(err.ravel())[::-1][: args.count]:
        y, x = divmod(int(i), args.res)
        print(f"pixel ({y}, {x}) r/R {np.hypot(y - cy, x - cx) / radius:.2f} table "
              f"{img['table'][y, x].round(3)} encoding {img['encoding'][y, x].round(3)} "
              f"share {err[y, x] / err.sum():.2f}")


if __name__ == "__main__":
    main()
