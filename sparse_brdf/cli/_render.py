"""``render`` and ``snr``: a Mitsuba scene rendered with measured materials, and the
rendering SNR of an image against a reference in both forms, beside HDR-FLIP."""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from ..decoders.layouts import DECODERS, LOBES, PLUGIN_DEFAULTS
from ..decoders.scene import DEFAULT_MEMORY_BUDGET, MEMORY_BUDGET_MIB
from ..errors import ImageFileError, UsageError
from ..evaluation.images import read_exr, read_mask, write_image, write_mask
from ..evaluation.render import (
    SHARED_PATHS,
    find_scene,
    noise_floor_snr,
    object_mask,
    parse_scene,
    render_scene,
)
from ..evaluation.scenes import (
    bsdf_ids,
    check_bsdf_ids,
    check_parameters,
    parse_defaults,
    parse_overrides,
)
from ..fileio import staged
from ..metrics import FLIP, OBJECT_ONLY, WHOLE_IMAGE, hdr_flip, snr_forms
from ..mitsuba_env import VARIANTS
from ..params import Interval
from ._options import IMAGE, MASK, RENDER, check_outputs, default_of, typed


def cmd_render(args: argparse.Namespace) -> int:
    """``render``: scenes with materials replaced, and an object mask on request; taken
    as Mitsuba's own ``mitsuba`` command takes them (several scenes, ``-o``, ``-D``)."""
    opts = {"decoder": args.decoder}
    if args.ensemble:
        opts["ensemble"] = args.ensemble
    t0 = time.perf_counter()
    scenes, materials = [find_scene(s) for s in args.scene], parse_overrides(args.material)
    for scene in scenes:
        check_bsdf_ids(scene, materials, "--material")
    if args.mask and not materials:
        raise UsageError("--mask: the object is the shapes of the replaced materials; give "
                         "--material ID=FILE")
    if args.mask and len(scenes) > 1:
        raise UsageError(f"--mask {args.mask}: one mask for {len(scenes)} scenes; render "
                         "each scene with its own --mask")
    outputs = _outputs(args.output, args.scene, scenes)
    check_outputs([*((o, IMAGE, "-o") for o in outputs), (args.mask, MASK, "--mask")],
                  [*scenes, *materials.values(), args.ensemble])
    defines = _settings_from_defines(args)
    for scene in scenes:
        check_parameters(scene, defines, "-D")
    images = [render_scene(scene, materials, spp=args.spp, seed=args.seed, res=args.res,
                           params=defines, sparse_options=opts, sampling=args.sampling,
                           variant=args.variant, memory_budget=args.memory_budget)
              for scene in scenes]
    mask = None
    if args.mask:
        mask = object_mask(scenes[0], res=(images[0].shape[1], images[0].shape[0]),
                           params=defines, materials=list(materials))
    seconds = time.perf_counter() - t0
    with staged([*outputs, *([args.mask] if args.mask else [])]) as tmp:
        for path, img in zip(tmp[:len(images)], images, strict=True):
            write_image(path, img, args.exposure)
        if mask is not None:
            write_mask(tmp[-1], mask)
    for out, img in zip(outputs, images, strict=True):
        print(f"wrote {out} ({img.shape[1]}x{img.shape[0]}, {args.spp} spp, "
              f"{args.sampling} sampling, {args.variant}"
              f"{', one channel' if img.shape[2] == 1 else ''}, {seconds:.2f} s)")
    if mask is not None:
        print(f"wrote {args.mask} (object mask: pixels whose camera rays first hit a shape "
              f"of {', '.join(materials)}; {int(mask.sum())} of {mask.size})")
    return 0


def _outputs(output: str | None, given: list[str], scenes: list[Path]) -> list[Path]:
    """Each scene's image, where Mitsuba's command writes it: ``-o FILE`` (one scene);
    ``-o DIR`` (an existing folder, or a name ending with a separator) as DIR/SCENE.exr;
    without ``-o``, SCENE.exr beside the scene file (a shipped scene's, given by name,
    in the current folder)."""
    folder = output is not None and (Path(output).is_dir() or output.endswith(("/", os.sep)))
    if output is not None and not folder:
        if len(scenes) > 1:
            raise UsageError(f"-o {output}: one file for {len(scenes)} scenes; give a folder "
                             "(-o DIR/: each image is DIR/SCENE.exr), or no -o (each beside "
                             "its scene)")
        return [Path(output)]
    out = [(Path(output) if folder else scene.parent if Path(name).is_file() else Path())
           / f"{scene.stem}.exr" for name, scene in zip(given, scenes, strict=True)]
    twice = sorted({str(o) for o in out if out.count(o) > 1})
    if twice:
        raise UsageError(f"{twice[0]}: two scenes of one name would both be written there; "
                         "render them one at a time with -o")
    return out


def _settings_from_defines(args: argparse.Namespace) -> dict[str, str]:
    """``-D`` as Mitsuba's command takes it: ``-D spp=N``, ``seed=N`` and ``res=N`` set
    what ``--spp``, ``--seed`` and ``--res`` set (on ``args``; one given both ways with
    two values is refused); the rest are the scene's parameters (name -> value)."""
    rest = []
    for item in args.define:
        key, eq, value = (t.strip() for t in item.partition("="))
        if not eq or key not in RENDER:
            rest.append(item)
            continue
        try:
            number = typed(RENDER[key])(value)
        except argparse.ArgumentTypeError as exc:
            raise UsageError(f"-D {key}: {exc}") from None
        if getattr(args, key) not in (number, default_of(render_scene, key)):
            raise UsageError(f"-D {key}={value}: --{key} {getattr(args, key)} given too; "
                             "give one")
        setattr(args, key, number)
    return parse_defaults(rest, "-D")


def _read_image(path: str, like: tuple[str, object] | None = None):
    """An EXR image that is finite and non-negative, and (``like``: (path, image)) of that
    image's size; every refusal names ``path``."""
    if Path(path).suffix.lower() in (".png", ".jpg", ".jpeg"):
        raise ImageFileError(f"{path}: a tone-mapped preview; the SNR and HDR-FLIP compare "
                             "linear images: give the .exr that `render -o NAME.exr` writes")
    img = read_exr(path)
    bad = int(np.size(img) - np.count_nonzero(np.isfinite(img)))
    if bad:
        raise ImageFileError(f"{path}: the image holds {bad} NaN or inf pixel values")
    negative = int(np.count_nonzero(img < 0))
    if negative:
        raise ImageFileError(f"{path}: the image holds {negative} negative pixel values; "
                             "HDR-FLIP scores non-negative radiance")
    if like is not None and img.shape != like[1].shape:
        raise ImageFileError(f"{path}: {img.shape[1]}x{img.shape[0]}, but {like[0]} is "
                             f"{like[1].shape[1]}x{like[1].shape[0]}")
    return img


def cmd_snr(args: argparse.Namespace) -> int:
    """``snr``: the rendering SNR in both forms, HDR-FLIP and the noise floor."""
    scene = find_scene(args.scene) if args.scene and not args.mask else None
    objects = None if scene is None else _object_materials(scene, args.material)
    ref = _read_image(args.reference)
    if not np.any(ref > 0):  # neither SNR (no signal) nor HDR-FLIP (no exposure range)
        raise ImageFileError(f"{args.reference}: the reference image is black (every pixel "
                             "0): the SNR and HDR-FLIP have nothing to compare against")
    img = _read_image(args.image, (args.reference, ref))
    ref2 = _read_image(args.reference2, (args.reference, ref)) if args.reference2 else None
    mask, why = None, None
    if args.mask:
        mask = read_mask(args.mask)
    elif scene is not None:
        mask = object_mask(scene, res=(ref.shape[1], ref.shape[0]), materials=objects)
    else:
        why = ("object-only not computed: give --scene SCENE (with --material ID) or --mask "
               "FILE to tell which pixels are the object")
    if mask is not None and mask.shape != ref.shape[:2]:
        raise ImageFileError(f"{args.mask or args.scene}: mask is {mask.shape[1]}x"
                             f"{mask.shape[0]}, the images {ref.shape[1]}x{ref.shape[0]}")
    if mask is not None and not mask.any():
        raise ImageFileError(f"{args.mask or args.scene}: the mask selects no pixel")
    whole = np.ones(ref.shape[:2], bool)
    snr = snr_forms(ref, img, whole if mask is None else mask)
    flip = hdr_flip(ref, img, mask).mean  # over the object's pixels; without a mask, all
    floor = None
    if ref2 is not None:
        floor = noise_floor_snr(ref, ref2, whole if mask is None else mask)
    if args.json:
        out = {"snr_whole_db": snr.whole,
               "snr_object_db": None if mask is None else snr.object,
               "flip_object": None if mask is None else flip,
               "object_pixels": None if mask is None else int(mask.sum()),
               "pixels": int(ref.shape[0] * ref.shape[1])}
        if mask is None:
            out["flip_whole"] = flip
        if why:
            out["object_missing"] = why
        if floor is not None:
            out.update(noise_floor_whole_db=floor.whole,
                       noise_floor_object_db=None if mask is None else floor.object)
        print(json.dumps(out))
    elif mask is None:
        print(f"{WHOLE_IMAGE} {snr.whole:.2f} dB, {FLIP} {flip:.4f} ({WHOLE_IMAGE} mean)"
              + (f" (noise floor: {WHOLE_IMAGE} {floor.whole:.2f} dB)" if floor else "")
              + f"; {why}")
    else:
        print(f"{snr}, {FLIP} {flip:.4f} ({OBJECT_ONLY} mean)"
              + (f" (noise floor: {floor})" if floor is not None else ""))
    return 0


def _object_materials(scene: Path, given: list[str]) -> list[str]:
    """The BSDF ids whose shapes are the object of ``snr --scene``: ``--material`` (IDs,
    or ID=FILE as render takes them), else the shipped scenes' ``material``."""
    root = parse_scene(scene).getroot()
    if given:
        ids = list(dict.fromkeys(g.partition("=")[0].strip() for g in given))
        check_bsdf_ids(scene, ids, "--material", root=root)
        return ids
    ids = bsdf_ids(root)
    if "material" in ids:
        return ["material"]
    raise UsageError(f"--scene {scene}: give --material ID, the id of the BSDF the images "
                     f"replaced, whose shapes are the object (the scene's BSDF ids: "
                     f"{', '.join(ids) or 'none'})")


def add_render(sub) -> None:
    """``render``."""
    r = sub.add_parser(
        "render", help="render a Mitsuba scene with materials overridden",
        description="Render any Mitsuba 3 scene file with some of its BSDFs (by id) replaced "
                    "by measured materials. spp, seed and the resolution fill the scene's "
                    "$spp, $seed and $res where it declares them, and are set on its "
                    "sampler and film otherwise; a scene's other parameters are set with -D. "
                    "It takes Mitsuba's own command line (scenes first, -o, -D KEY=VALUE, "
                    "-m VARIANT): `sparse-brdf render scene.xml` renders what `mitsuba "
                    "scene.xml` would, and also scenes whose BSDFs are of type sparse_brdf, "
                    "tabulated_brdf or neural_brdf, for which `mitsuba` says \"Plugin not "
                    "found\" (the plugins register from Python).",
        epilog="examples:\n  sparse-brdf render scene.xml other.xml -D spp=16 -o out/   "
               "# as `mitsuba scene.xml other.xml ...`, whose plugin lookup knows no "
               "sparse_brdf\n"
               "  sparse-brdf convert mitsuba:au-ggx-0.08 gold.binary\n"
               "  sparse-brdf encode gold.binary -o gold.sbrdf\n"
               "  sparse-brdf render sphere -o ref.exr --material material=gold.binary "
               f"--sampling {SHARED_PATHS}\n"
               "  sparse-brdf render sphere -o model.exr --material material=gold.sbrdf "
               f"--sampling {SHARED_PATHS} --mask mask.exr\n"
               "  sparse-brdf snr ref.exr model.exr --mask mask.exr\n"
               "  sparse-brdf render sphere -o look.png --material material=gold.sbrdf "
               "--exposure 1")
    r.add_argument("scene", nargs="+",
                   help="scene XML: any Mitsuba 3 scene file, or the name of a shipped scene "
                        "(sphere, spheres, sphere_light, paper_sphere); several are rendered "
                        "one after the other, as Mitsuba's `mitsuba` command does")
    r.add_argument("-o", "--output",
                   help="output image: .exr (linear HDR, float32) or .png/.jpg (an 8-bit "
                        "sRGB preview, see --exposure); or a folder (an existing one, or "
                        "DIR/) that gets SCENE.exr per scene (default: SCENE.exr beside each "
                        "scene file, a shipped scene's in the current folder)")
    r.add_argument("--material", action="append", default=[], metavar="ID=FILE",
                   help="replace BSDF ID: a .sbrdf selects sparse_brdf, any other BRDF "
                        "source tabulated_brdf (repeatable; default: none, the scene as it "
                        "is)")
    r.add_argument("-D", "--define", action="append", default=[], metavar="KEY=VALUE",
                   help="set a parameter the scene uses as $KEY, e.g. -D envrot=90; "
                        "-D spp=N, seed=N, res=N are --spp, --seed, --res (repeatable; "
                        "default: the scene's values)")
    r.add_argument("--spp", type=typed(RENDER["spp"]), default=default_of(render_scene, "spp"),
                   help="samples per pixel")
    r.add_argument("--seed", type=typed(RENDER["seed"]), default=default_of(render_scene, "seed"),
                   help="the sampler's seed: the same seed and spp give the same image")
    r.add_argument("--res", type=typed(RENDER["res"]), default=default_of(render_scene, "res"),
                   help="the film's longer side in pixels, its aspect ratio kept (the "
                        "scene's $res where it declares one; default: the scene's film)")
    r.add_argument("--exposure", type=typed(Interval(float, -64.0, 64.0)), default=0.0,
                   metavar="STOPS",
                   help="a .png/.jpg preview's exposure: values times 2^STOPS before the "
                        "sRGB curve (an .exr is written as rendered)")
    r.add_argument("--sampling", default=PLUGIN_DEFAULTS["sampling"], choices=LOBES,
                   help="BSDF sampling of the replaced materials: lobe (the plugins' "
                        "default) follows each material's highlight, the lower noise for "
                        f"looking at an image; {SHARED_PATHS} gives every material the same "
                        "sample paths for one seed and spp, so renders to compare (snr) "
                        "share their noise")
    _add_decoder_options(r)
    r.add_argument("-m", "--variant", default=default_of(render_scene, "variant"),
                   choices=VARIANTS, metavar="VARIANT",
                   help="Mitsuba's variant (%(choices)s; the CUDA ones need an NVIDIA "
                        "GPU). A spectral variant's image is RGB, converted by Mitsuba's "
                        "film; a mono variant's is one channel: Y in an .exr, a greyscale "
                        ".png/.jpg")
    r.add_argument("--mask", metavar="MASK.exr",
                   help="also write the object mask (.exr or .npy; 1 where camera rays first "
                        "hit a shape of a replaced material), for `sparse-brdf snr --mask` "
                        "(default: none)")
    r.set_defaults(func=cmd_render)


def _add_decoder_options(r) -> None:
    """``render``'s options for the sparse_brdf plugin: decoder, memory budget, ensemble."""
    r.add_argument("--decoder", default=PLUGIN_DEFAULTS["decoder"], choices=DECODERS,
                   help="how the sparse_brdf plugin evaluates .sbrdf materials: grouped "
                        "tables (fastest), strict (a loop over the terms: least memory), or "
                        "auto: grouped unless its tables would be too large or the "
                        "scene's --memory-budget is spent")
    r.add_argument("--memory-budget", type=typed(MEMORY_BUDGET_MIB), metavar="MIB",
                   default=default_of(render_scene, "memory_budget"),
                   help="the scene's budget of per-material decoder data, in MiB, for "
                        "its auto-decoded .sbrdf materials: the fast tables go to the "
                        "materials that gain most per byte while they fit, the others "
                        "take the compact decoder (default: the plugin's, "
                        f"{DEFAULT_MEMORY_BUDGET // 2**20} MiB)")
    r.add_argument("--ensemble", help="ensemble .npz for .sbrdf materials "
                   "(default: the shipped one each file names)")


def add_snr(sub) -> None:
    """``snr``."""
    n = sub.add_parser(
        "snr", help="rendering SNR (dB) of an image against a reference, in both forms",
        description="Rendering SNR 10 log10(sum ref^2 / sum (ref - img)^2) in two forms: "
                    "whole-image (every pixel, background included: the paper's form) and "
                    "object-only (the pixels whose camera rays first hit a shape carrying a "
                    "replaced material; the strict form). The object pixels come from the "
                    "scene (--scene, traced at the images' size) or from a mask file (--mask, "
                    "e.g. written by `sparse-brdf render --mask`); without either, only the "
                    "whole-image form is printed. Beside them it prints HDR-FLIP, the "
                    "perceptual difference of the two HDR images (0 = identical, 1 = most "
                    "different; a 10 % brightness change scores about 0.1), averaged over "
                    "the object's pixels (every pixel without a mask).",
        epilog="example:\n  sparse-brdf snr ref.exr model.exr --scene sphere "
               "--reference2 ref-seed1.exr",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    n.add_argument("reference", help="reference EXR")
    n.add_argument("image", help="image EXR")
    where = n.add_mutually_exclusive_group()
    where.add_argument("--scene", help="the scene the images were rendered from (a path or a "
                                       "shipped scene name): its object mask is traced at "
                                       "the images' size (default: none)")
    where.add_argument("--mask", help="object mask: an EXR (nonzero = object) or a .npy of "
                                      "booleans, the images' size (default: none; without "
                                      "--scene or --mask only the whole-image SNR is printed)")
    n.add_argument("--material", action="append", default=[], metavar="ID",
                   help="with --scene: the id of a BSDF the images replaced; the shapes "
                        "carrying it are the object (repeatable; default: the shipped "
                        "scenes' material)")
    n.add_argument("--reference2", help="a second reference (other seed): prints the noise "
                                        "floor beside the SNR (default: none)")
    n.add_argument("--json", action="store_true", help="print JSON")
    n.set_defaults(func=cmd_snr)
