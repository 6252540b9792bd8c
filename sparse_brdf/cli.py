"""The ``sparse-brdf`` command line. Each subcommand is a thin wrapper of a library call."""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import inspect
import json
import math
import os
import signal
import sys
import textwrap
import time
import traceback
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .coords import GRID_BINS, GRID_SIDE, check_grid
from .errors import (
    BRDFFileError,
    EnsembleMismatchError,
    ImageFileError,
    InvalidBRDFError,
    OutputError,
    SparseBRDFError,
    UsageError,
    one_line,
)
from .evaluation import fit_images as fit_images_module
from .evaluation.acquisition import PRIORS
from .evaluation.acquisition_bench import KIND as ACQUISITION
from .evaluation.acquisition_bench import (
    AcquisitionBench,
    AcquisitionConfig,
    check_acquisition_config,
)
from .evaluation.batch import (
    PLAN_PAIRS,
    encode_batch,
    encode_file,
    encode_samples_file,
    is_batch,
    plan_samples_file,
    samples_constant,
)
from .evaluation.bench import Bench, BenchConfig, check_config, config_kind, shipped_configs
from .evaluation.fit_images import fit_images, load_views
from .evaluation.fit_scene import fit_scene
from .evaluation.ranking import RANK_BY, merge_results, write_ranking
from .evaluation.render import (
    IMAGE_SUFFIXES,
    MASK_SUFFIXES,
    RENDER_PARAMETERS,
    SHARED_PATHS,
    find_scene,
    noise_floor_snr,
    object_mask,
    parse_defaults,
    parse_overrides,
    parse_scene,
    read_exr,
    read_mask,
    render_scene,
    write_image,
    write_mask,
)
from .fileio import (
    check_output,
    check_suffix,
    check_writable,
    cleanup_on_signals,
    remove_temporaries,
    staged,
)
from .metrics import FLIP, OBJECT_ONLY, WHOLE_IMAGE, hdr_flip, snr_forms
from .model import acquire as acquire_module
from .model import budget as budget_module
from .model import encode as encode_module
from .model import train as train_module
from .model.budget import encode_to_bytes
from .model.encode import (
    DEFAULT_FILL_ITERS,
    DEFAULT_N_COEFFS,
    PAPER_OPTIONS,
    check_n_coeffs,
    encode,
)
from .model.ensemble import Ensemble, resolve_ensemble
from .model.interpolate import PARAMETERS as INTERPOLATE
from .model.interpolate import interpolate
from .model.layouts import DECODERS, PLUGIN_DEFAULTS, SAMPLING
from .model.sbrdf import decode_file, load_sbrdf, save_sbrdf
from .model.specs import parse_spec
from .model.train import train_dictionaries, train_ensemble
from .parallel import executor
from .params import Interval
from .sources.corpora import SPLITS, TRAINING_CORPORA, get_corpus, list_corpora
from .sources.dataset import training_data
from .sources.load import load_brdf
from .sources.merl import write_merl
from .sources.samples import PLACEMENTS, plan, read_samples
from .transforms import COLOUR_BASES, TRANSFORMS

EPILOG = f"""examples (built-in materials and shipped scenes; nothing to download):
  sparse-brdf corpus list mitsuba
  sparse-brdf info mitsuba:au-ggx-0.08
  sparse-brdf convert mitsuba:au-ggx-0.08 gold.binary
  sparse-brdf encode gold.binary -o gold.sbrdf --coeffs {DEFAULT_N_COEFFS}
  sparse-brdf decode gold.sbrdf -o gold-decoded.binary
  sparse-brdf render sphere -o gold.png --material material=gold.sbrdf
  sparse-brdf train --corpus mitsuba -o my_ensemble.npz --checkpoint-dir ckpt/

Outputs follow their names: each -o takes the suffix of what the command
writes (a .sbrdf, a MERL .binary, an .exr or .png/.jpg image, ...); another
suffix, or a name ending in / (a folder), is refused before any work.
"""


#: The declared parameters the options take their bounds and choices from.
ENCODE, TRAIN, RENDER = (encode_module.PARAMETERS, train_module.PARAMETERS, RENDER_PARAMETERS)
#: Coefficients per channel: at most the MERL grid's entries (no channel holds more).
COEFFS = ENCODE["n_coeffs"].capped(GRID_BINS.hi)


def _typed(c: Interval):
    """An argparse type from a declared :class:`~sparse_brdf.params.Interval`: the value,
    or a one-line message saying what the option takes."""
    def value(text: str) -> int | float:
        try:
            v = int(text) if c.kind is int else float(text)
        except ValueError:
            what = "an integer" if c.kind is int else "a number"
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if v not in c:
            raise argparse.ArgumentTypeError(f"must be {c.describe()}, got {text}")
        return v
    return value


def _default(func, name: str):
    """The default of ``func``'s parameter ``name`` (a tuple as a list): what an option
    that stands for it defaults to."""
    d = inspect.signature(func).parameters[name].default
    return list(d) if isinstance(d, tuple) else d


#: The kinds of file the commands write: their suffixes and what they are called.
SBRDF = ((".sbrdf",), "a .sbrdf coefficient file")
MERL = ((".binary",), "a MERL .binary file")
ENSEMBLE_NPZ = ((".npz",), "an ensemble .npz file")
SAMPLES_FILE = ((".csv", ".npz"), "a samples .csv or .npz file")
IMAGE = (IMAGE_SUFFIXES, "an image (.exr: linear HDR; .png, .jpg: an sRGB preview)")
MASK = (MASK_SUFFIXES, "an object mask (.exr or .npy)")


def _check_outputs(outputs, inputs) -> None:
    """Check every output of a command before its work: ``outputs`` are (path, kind,
    option) with ``kind`` one of the kinds above (None paths skipped). Each must take
    its kind's suffix, not name a folder, be none of the ``inputs`` nor another output,
    and be writable."""
    done: list = []
    for out, (suffixes, kind), option in outputs:
        if not out:
            continue
        check_suffix(out, suffixes, option, kind)
        check_output(out, [*inputs, *done])
        check_writable(out)
        done.append(out)


def _add_source_help(p: argparse.ArgumentParser) -> None:
    p.epilog = ("A BRDF source is a MERL/DTU .binary file, a Neural-BRDF .h5 file, a .sbrdf "
                "coefficient file, or mitsuba:<name> for a built-in material.")


def cmd_corpus_list(args: argparse.Namespace) -> int:
    if args.corpus:
        c = get_corpus(args.corpus)
        test = {m.name for m in c.split("test")}
        for m in c.materials:
            print(one_line(f"{m.name:40s} {'test' if m.name in test else 'train':5s} "
                           f"{m.source}"))
        return 0
    for name, desc in list_corpora().items():
        print(f"{name:8s} {desc}")
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    info = load_brdf(args.source, symmetrize=args.symmetrize).summary()
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    print(f"name        {one_line(info['name'])}\nsource      {one_line(info['source'])}")
    print(f"shape       {tuple(info['shape'])}")
    print(f"valid bins  {info['valid_bins']} of {info['total_bins']}")
    for i, ch in enumerate("RGB"):
        print(f"{ch}           min {info['min'][i]:.4g}  max {info['max'][i]:.4g}  "
              f"mean {info['mean'][i]:.4g}  albedo {info['albedo'][i]:.3f}")
    return 0


def cmd_convert(args: argparse.Namespace) -> int:
    out = Path(args.output)
    _check_outputs([(out, MERL, "output")], [args.source])
    write_merl(out, load_brdf(args.source, symmetrize=args.symmetrize))
    print(f"wrote {out}")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    materials = []
    for name in args.corpus:
        materials += get_corpus(name).split(args.split)
    shape = check_grid(args.grid, "--grid")
    if max(args.taus) > math.prod(shape):
        raise UsageError(f"--taus {max(args.taus)}: a tensor of that grid has only "
                         f"{math.prod(shape)} coefficients")
    _check_outputs([(args.output, ENSEMBLE_NPZ, "-o")], [args.extend])
    t0 = time.perf_counter()
    data = training_data(materials, args.transform, shape, basis=args.basis,
                         symmetrize=args.symmetrize)
    x = data.x
    if args.dicts > len(x):
        raise UsageError(f"--dicts {args.dicts}: more dictionaries than the {len(x)} "
                         "training tensors")
    load_s = time.perf_counter() - t0
    meta = {
        "data": [f"{m.corpus}/{m.name}" for m in materials],
        "corpora": args.corpus, "split": args.split, "transforms": list(args.transform),
        "basis": args.basis, "grid": list(shape), "load_seconds": load_s,
        "data_sha256": data.digest(), "symmetrize": args.symmetrize is not False,
        "command": "sparse-brdf " + " ".join(sys.argv[1:]),
        "created": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
    }
    ens = train_ensemble(x, args.taus, args.dicts, args.iterations, seed=args.seed,
                         checkpoint_dir=args.checkpoint_dir, meta=meta,
                         reassign_every=args.reassign_every, masked=args.masked,
                         missing=data.missing, init=args.init, tol=args.tol,
                         max_moved=args.max_moved, shard_tensors=args.shard_tensors,
                         workers=args.workers, scheduler=args.scheduler)
    if args.extend:
        ens = Ensemble.load(args.extend).union(ens)
    ens.save(args.output)
    print(f"wrote {args.output}: {ens.n_dicts} dictionaries, id {ens.id}, "
          f"trained in {ens.meta.get('seconds', 0):.0f} s on {len(x)} tensors")
    return 0


def cmd_encode(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    options = {"max_error": args.max_error, "transform": args.transform,
               "fill_iters": args.fill_iters, "budget": args.budget,
               "selector": args.selector, "fill": args.fill, "basis": args.basis}
    if args.paper:
        options.update(PAPER_OPTIONS)
    if args.symmetrize is not None:
        options["symmetrize"] = args.symmetrize
    if is_batch(args.source):
        if Path(args.output).is_file():
            raise OutputError(f"-o {args.output}: a batch writes a folder (one .sbrdf per "
                              "material and its summary), not a file")
        if args.bytes is not None:
            raise UsageError("--bytes: byte budgets encode one material at a time (not a "
                             "batch yet); give --coeffs for a batch")
        with executor(args.workers, args.scheduler) as ex:
            summary = encode_batch(args.source, args.output, args.ensemble,
                                   {"n_coeffs": args.coeffs, **options}, ex)
        _note_capped(args, summary["grid"])
        return _report_batch(args, summary)
    _check_outputs([(args.output, SBRDF, "-o")], [args.source, args.ensemble])
    path, model = encode_file(args.source, args.output, args.ensemble, args.coeffs,
                              args.bytes, **options)
    _note_capped(args, model.shape)
    seconds = time.perf_counter() - t0
    info = {"output": str(path), "bytes": path.stat().st_size, "seconds": seconds,
            "transform": model.transform, "coefficients": model.n_coeffs.tolist(),
            "dictionaries": model.dict_index.tolist(), **model.stats}
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    st = model.stats["transforms"][model.transform]
    print(f"wrote {path} ({info['bytes']} bytes): {model.transform}, coefficients "
          f"{info['coefficients']}, dictionaries {info['dictionaries']}, "
          f"RAE {st['rae']:.4f}, gamma-MSE {st['gamma_mse']:.3g}, {seconds:.2f} s")
    return 0


def cmd_encode_samples(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    _check_outputs([(args.output, SBRDF, "-o")], [args.samples, args.ensemble])
    samples = read_samples(args.samples)
    if samples_constant(samples) and np.any(samples.rgb):  # all zeros: refused below
        print(f"sparse-brdf: warning: {args.samples}: every sample has the same value "
              f"{samples.rgb[0].tolist()}: a Lambertian material, or values not measured "
              "(a plan's zeros or one value copied into every row)", file=sys.stderr)
    path, model = encode_samples_file(samples, args.output, args.ensemble, args.coeffs,
                                      args.bytes, seed=args.seed, prior=args.prior)
    st = model.stats
    print(f"wrote {path} ({path.stat().st_size} bytes) from {st['samples']} samples: "
          f"{model.transform}, coefficients {model.n_coeffs.tolist()}, dictionaries "
          f"{model.dict_index.tolist()}; {time.perf_counter() - t0:.1f} s in all (the "
          f"sparse fit {st['seconds']:.1f} s)")
    return 0


def cmd_plan_samples(args: argparse.Namespace) -> int:
    _check_outputs([(args.output, SAMPLES_FILE, "-o")], [])
    path = plan_samples_file(args.output, args.n, args.placement, args.seed)
    print(f"wrote {path}: {args.n} direction pairs ({args.placement}); measure them and "
          "fill in r,g,b")
    return 0


def _report_batch(args: argparse.Namespace, summary: dict) -> int:
    """Print a batch's summary; exit status 1 if any material failed."""
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"{args.output}: {summary['encoded']} encoded, {summary['skipped']} skipped "
              f"(done before), {summary['failed']} failed of {summary['materials']} "
              f"in {summary['seconds']:.1f} s; wrote summary.csv, summary.json")
        for r in summary["rows"]:
            if r["status"] == "failed":
                print(f"  failed: {r['source']}: {r['error']}", file=sys.stderr)
    return 1 if summary["failed"] else 0


def _add_where(p: argparse.ArgumentParser, what: str) -> None:
    """``--workers N`` / ``--scheduler ADDRESS``: where ``what`` runs (``parallel.py``)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, metavar="N",
                   help=f"run {what} on a local Dask cluster of N processes (default: in "
                        "this process, no cluster)")
    g.add_argument("--scheduler", metavar="ADDRESS",
                   help=f"run {what} on an existing Dask cluster (e.g. tcp://host:8786; "
                        "default: in this process)")


def _note_capped(args: argparse.Namespace, shape: tuple[int, ...]) -> None:
    """``--coeffs`` is a maximum: the library caps it at a channel's entries. Say so on
    stderr when the user gave a number beyond the grid; the default stays silent."""
    most = math.prod(shape)
    if args.coeffs_given and args.coeffs > most:
        print(f"sparse-brdf: note: --coeffs {args.coeffs}: a channel of the "
              f"{'x'.join(map(str, shape))} grid holds {most} coefficients; encoded at "
              f"most {most}", file=sys.stderr)


class _Given(argparse.Action):
    """Store an option's value and record that the user gave it (``DEST_given``)."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values)
        setattr(namespace, f"{self.dest}_given", True)


def cmd_decode(args: argparse.Namespace) -> int:
    _check_outputs([(args.output, MERL, "-o")], [args.source, args.ensemble])
    try:
        brdf = decode_file(args.source, args.ensemble)
    except InvalidBRDFError as exc:  # e.g. coefficients so large that the values overflow
        raise BRDFFileError(f"{args.source}: decodes to unusable values: {exc}") from exc
    write_merl(args.output, brdf)
    print(f"wrote {args.output}")
    return 0


def cmd_blend(args: argparse.Namespace) -> int:
    _check_outputs([(args.output, SBRDF, "-o")], [args.a, args.b, args.ensemble])
    try:  # the shipped ensemble A names, unless one is given
        ens = resolve_ensemble(args.ensemble, for_id=load_sbrdf(args.a).ensemble_id)
    except EnsembleMismatchError as exc:
        raise EnsembleMismatchError(f"{args.a}: {exc}") from exc
    n = None if args.coeffs is None else check_n_coeffs(args.coeffs, ens)
    _note_capped(args, ens.shape)
    a = load_sbrdf(args.a, ens)
    try:
        b = load_sbrdf(args.b, ens)
    except EnsembleMismatchError as exc:
        raise EnsembleMismatchError(
            f"{args.b}: encoded with another ensemble than {args.a} ({ens.id}): blending "
            f"needs one ensemble; re-encode the material of {args.b} with it (sparse-brdf "
            f"encode SOURCE -o NEW.sbrdf --ensemble {args.ensemble or ens.id})") from exc
    if a.transform != b.transform:
        raise UsageError(f"cannot blend {args.a} ({a.transform}) with {args.b} "
                         f"({b.transform}): encode both with the same --transform")
    out = save_sbrdf(args.output, interpolate(a, b, args.alpha, ens, n))
    print(f"wrote {out}")
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    opts = {"decoder": args.decoder}
    if args.ensemble:
        opts["ensemble"] = args.ensemble
    t0 = time.perf_counter()
    scene, materials = find_scene(args.scene), parse_overrides(args.material)
    if args.mask and not materials:
        raise UsageError("--mask: the object is the shapes of the replaced materials; give "
                         "--material ID=FILE")
    _check_outputs([(args.output, IMAGE, "-o"), (args.mask, MASK, "--mask")],
                   [scene, *materials.values(), args.ensemble])
    defines = parse_defaults(args.define, "-D")
    img = render_scene(scene, materials, spp=args.spp, seed=args.seed, res=args.res,
                       params=defines, sparse_options=opts, sampling=args.sampling)
    mask = None
    if args.mask:
        mask = object_mask(scene, res=(img.shape[1], img.shape[0]), params=defines,
                           materials=list(materials))
    seconds = time.perf_counter() - t0
    with staged([args.output, *([args.mask] if args.mask else [])]) as tmp:
        write_image(tmp[0], img, args.exposure)
        if mask is not None:
            write_mask(tmp[1], mask)
    print(f"wrote {args.output} ({img.shape[1]}x{img.shape[0]}, {args.spp} spp, "
          f"{args.sampling} sampling, {seconds:.2f} s)")
    if mask is not None:
        print(f"wrote {args.mask} (object mask: pixels whose camera rays first hit a shape "
              f"of {', '.join(materials)}; {int(mask.sum())} of {mask.size})")
    return 0


def _read_image(path: str, like: tuple[str, object] | None = None):
    """An EXR image that is finite, and (``like``: (path, image)) of that image's size."""
    if Path(path).suffix.lower() in (".png", ".jpg", ".jpeg"):
        raise ImageFileError(f"{path}: a tone-mapped preview; the SNR and HDR-FLIP compare "
                             "linear images: give the .exr that `render -o NAME.exr` writes")
    img = read_exr(path)
    bad = int(np.size(img) - np.count_nonzero(np.isfinite(img)))
    if bad:
        raise ImageFileError(f"{path}: the image holds {bad} NaN or inf pixel values")
    if like is not None and img.shape != like[1].shape:
        raise ImageFileError(f"{path}: {img.shape[1]}x{img.shape[0]}, but {like[0]} is "
                             f"{like[1].shape[1]}x{like[1].shape[0]}")
    return img


def cmd_snr(args: argparse.Namespace) -> int:
    ref = _read_image(args.reference)
    img = _read_image(args.image, (args.reference, ref))
    ref2 = _read_image(args.reference2, (args.reference, ref)) if args.reference2 else None
    mask, why = None, None
    if args.mask:
        mask = read_mask(args.mask)
    elif args.scene:
        scene = find_scene(args.scene)
        mask = object_mask(scene, res=(ref.shape[1], ref.shape[0]),
                           materials=_object_materials(scene, args.material))
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
    if given:
        return [g.partition("=")[0].strip() for g in given]
    ids = {e.get("id") for e in parse_scene(scene).getroot().iter("bsdf") if e.get("id")}
    if "material" in ids:
        return ["material"]
    raise UsageError(f"--scene {scene}: give --material ID, the id of the BSDF the images "
                     f"replaced, whose shapes are the object (the scene's BSDF ids: "
                     f"{', '.join(sorted(ids)) or 'none'})")


def cmd_fit_scene(args: argparse.Namespace) -> int:
    if Path(args.output).exists() and not Path(args.output).is_dir():
        raise OutputError(f"-o {args.output}: fit-scene writes a folder (a .sbrdf per "
                          "material and fit-scene.md), not a file")
    check_writable(Path(args.output) / "fit-scene.md")
    rep = fit_scene(find_scene(args.scene), args.target_snr, parse_overrides(args.material),
                    args.output, ensemble_path=args.ensemble, spp=args.spp, res=args.res,
                    seed=args.seed, max_bytes=args.bytes)
    print(f"scene SNR with every material sparse: object-only "
          f"{rep['scene_snr_all_sparse']:.1f} dB, whole-image "
          f"{rep['scene_snr_all_sparse_whole']:.1f} dB; "
          f"{rep['bytes_total']} bytes of coefficients; wrote {args.output}/fit-scene.md")
    return 0


def cmd_fit_images(args: argparse.Namespace) -> int:
    scene = find_scene(args.scene)
    validation = args.validation_view or []
    paths = [*(fit_images_module.parse_view(v)[0] for v in args.view),
             *(fit_images_module.parse_view(v, "--validation-view")[0] for v in validation)]
    _check_outputs([(args.output, SBRDF, "-o")], [args.start, *paths])
    views = load_views(args.view, read_exr)
    held = load_views(validation, read_exr, option="--validation-view")
    result = fit_images(scene, views, args.start, material=args.material,
                        ensemble=args.ensemble, iterations=args.iterations, lr=args.lr,
                        lr_end=args.lr_end, spp=args.spp, seed=args.seed,
                        checkpoint_dir=args.checkpoint_dir, decoder=args.decoder,
                        variant=args.variant, optimizer=args.optimizer,
                        loss=args.loss, prior_weight=args.prior_weight, validation=held,
                        validate_every=args.validate_every)
    save_sbrdf(args.output, result.model)
    snr = result.snr_db
    print(f"wrote {args.output}: {result.iterations} iterations in {result.seconds:.0f} s "
          f"({result.seconds_per_iteration:.2f} s each); the views' mean whole-image SNR "
          f"{snr[0]:.1f} dB at the start, {snr[-1]:.1f} dB at the last iteration")
    if result.best_evaluation is not None:
        best = dict(result.validation_snr_db)[result.best_evaluation]
        print(f"kept the iterate after {result.best_evaluation} evaluations: the "
              f"validation views' whole-image SNR {result.validation_snr_db[0][1]:.1f} dB "
              f"at the start, {best:.1f} dB there")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    if args.config is not None and config_kind(args.config) == ACQUISITION:
        return _bench_acquisition(args)
    cfg = BenchConfig.load(args.config)
    if args.out:
        cfg.out = args.out
    if args.no_render:
        cfg.render = False
    if args.model:
        if not args.out:  # the config's folder holds its own models' results
            raise UsageError(f"--model: give --out too, a folder of its own (the results of "
                             f"{cfg.label}'s models in {cfg.out} would be replaced)")
        for spec in args.model:
            try:  # the grammar; check_config imports and checks each model
                parse_spec(spec)
            except UsageError as exc:
                raise UsageError(f"--model: {exc}") from None
        cfg.models = list(args.model)
    plan = check_config(cfg)  # a config the run would refuse fails here, before any work
    if args.check:
        skipped = "".join(f"; skips {k}: {v}" for k, v in plan["skipped_scenes"].items())
        print(f"{cfg.label}: ok: {plan['materials']} materials x {len(plan['models'])} "
              f"models, {plan['training']} training materials, scenes "
              f"{', '.join(plan['scenes']) or 'none'}{skipped}")
        return 0
    with executor(args.workers, args.scheduler) as ex:
        Bench(cfg).run(ex)
    print(f"wrote {cfg.out}/report.md, report.html, results.csv, results.json")
    return 0


def cmd_bench_merge(args: argparse.Namespace) -> int:
    merged = merge_results(args.results, by=args.by)
    paths = write_ranking(merged, args.output)
    print(f"ranked {len(merged['rows'])} models of {len(args.results)} results files: wrote "
          f"{', '.join(str(p) for p in paths)}")
    return 0


def _bench_acquisition(args: argparse.Namespace) -> int:
    cfg = AcquisitionConfig.load(args.config)
    if args.out:
        cfg.out = args.out
    if args.model:
        raise UsageError(f"--model: the acquisition bench ({cfg.label}) compares encodings "
                         "from samples, the sparse model and PCA; it takes no --model")
    if args.no_render or args.workers or args.scheduler:
        given = "--no-render" if args.no_render else "--workers/--scheduler"
        raise UsageError(f"{given}: the acquisition bench ({cfg.label}) renders every fit "
                         "here; run it without that option")
    plan = check_acquisition_config(cfg)
    if args.check:
        skipped = "".join(f"; skips {k}: {v}" for k, v in plan["skipped_scenes"].items())
        print(f"{cfg.label}: ok: {plan['materials']} materials x {plan['cells']} fits, "
              f"scenes {', '.join(plan['scenes'])}{skipped}")
        return 0
    AcquisitionBench(cfg).run()
    print(f"wrote {cfg.out}/report.md, results.csv, results.json")
    return 0


class _Help(argparse.RawDescriptionHelpFormatter):
    """Descriptions and epilogs line by line: a long line is wrapped, an indented one
    (an example command) kept as written; every option's help ends with its default
    (unless it says it itself; flags are off by default; required options have none)."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return "\n".join(
            line if line[:1].isspace() or len(line) + len(indent) <= width
            else textwrap.fill(line, width, initial_indent=indent, subsequent_indent=indent)
            for line in text.splitlines())

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        said = any(w in text for w in ("%(default)", "(default", "default:", "default per"))
        if (said or not action.option_strings or action.required
                or any(action.default is v for v in (None, False, argparse.SUPPRESS))):
            return text
        return f"{text} (default: %(default)s)"


def parsers(parser: argparse.ArgumentParser):
    """``parser`` and every sub-command's parser below it."""
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in dict.fromkeys(action.choices.values()):
                yield from parsers(sub)


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr (exit status 2); its
    subparsers are of the same class."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="sparse-brdf",
        description="Measured BRDFs as sparse coefficients over a learned dictionary "
                    "ensemble: convert, inspect, train, encode, decode and render.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--debug", action="store_true",
                   help="on an error, print the traceback too (anywhere on the line; or set "
                        "SPARSE_BRDF_DEBUG=1)")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in (_add_data_commands, _add_train, _add_codec_commands, _add_render, _add_snr,
                _add_fit_scene, _add_fit_images, _add_blend_and_bench):  # in the order of the help
        add(sub)
    for q in parsers(p):
        q.formatter_class = _Help
    return p


def _add_data_commands(sub) -> None:
    """``corpus list``, ``info`` and ``convert``."""
    c = sub.add_parser("corpus", help="list corpora and their train/test split")
    csub = c.add_subparsers(dest="corpus_command", required=True, metavar="ACTION")
    cl = csub.add_parser("list", help="list corpora, or the materials of one corpus")
    cl.add_argument("corpus", nargs="?",
                    help="a corpus name (mitsuba, merl-demo, merl, rgl, abc, sgd) or a folder")
    cl.set_defaults(func=cmd_corpus_list)

    i = sub.add_parser("info", help="shape, valid bins, value range and albedo of a BRDF")
    i.add_argument("source", help="BRDF source (see below)")
    i.add_argument("--json", action="store_true", help="print JSON")
    _add_symmetrize(i)
    _add_source_help(i)
    i.set_defaults(func=cmd_info)

    v = sub.add_parser("convert", help="tabulate any BRDF source into a MERL .binary file")
    v.add_argument("source", help="BRDF source (see below)")
    v.add_argument("output", help="output .binary path (written atomically)")
    _add_symmetrize(v)
    _add_source_help(v)
    v.set_defaults(func=cmd_convert)


def _add_symmetrize(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-symmetrize", dest="symmetrize", action="store_const", const=False,
                   default=None,
                   help="keep a Neural-BRDF network as it is (default: averaged over the "
                        "mirror phi_d -> -phi_d and reciprocity phi_d -> phi_d + pi, as an "
                        "isotropic BRDF is; docs/method.md, \"Symmetric references\")")


def _add_train(sub) -> None:
    t = sub.add_parser("train", help="train a dictionary ensemble (docs/method.md, Training)")
    t.add_argument("--corpus", nargs="+", default=list(TRAINING_CORPORA),
                   help="corpora to train on (names or folders)")
    t.add_argument("--split", default="train", choices=SPLITS,
                   help="which materials of the corpora to train on")
    t.add_argument("--transform", nargs="+", default=_default(training_data, "transforms"),
                   choices=TRANSFORMS,
                   help="value transforms the dictionaries are trained in, one set each (the "
                        "paper's ensembles: log-plus log-plus-cosine)")
    _add_symmetrize(t)
    t.add_argument("--basis", default=_default(training_data, "basis"), choices=COLOUR_BASES,
                   help="colour basis of the training channels (the encoder's coded channels)")
    t.add_argument("--taus", nargs="+", type=_typed(TRAIN["tau"].capped(GRID_BINS.hi)),
                   default=_default(train_ensemble, "taus"),
                   help="training sparsities; one set of dictionaries per value")
    t.add_argument("--dicts", type=_typed(TRAIN["n_dicts"]),
                   default=_default(train_ensemble, "n_dicts"), help="dictionaries per sparsity")
    t.add_argument("--iterations", type=_typed(TRAIN["n_iter"]),
                   default=_default(train_ensemble, "n_iter"),
                   help="at most this many iterations per sparsity")
    t.add_argument("--reassign-every", type=_typed(TRAIN["reassign_every"]),
                   default=_default(train_dictionaries, "reassign_every"),
                   help="cluster against every dictionary at every N-th iteration")
    t.add_argument("--tol", type=_typed(TRAIN["tol"]), default=_default(train_dictionaries, "tol"),
                   help="stop once an iteration lowers the objective by less than this "
                        "(relative) and the latest clustering moved at most --max-moved")
    t.add_argument("--max-moved", type=_typed(TRAIN["max_moved"]),
                   default=_default(train_dictionaries, "max_moved"),
                   help="fraction of tensors a clustering may move for training to stop")
    t.add_argument("--shard-tensors", type=_typed(TRAIN["shard_tensors"]),
                   default=_default(train_dictionaries, "shard_tensors"),
                   help="tensors per shard: sums over tensors run per shard, then over "
                        "the shards, so this fixes the floating-point order (any executor "
                        "gives the same result for one value); 0: one shard of all, the "
                        "order that trained the shipped default ensemble (docs/ensemble.md)")
    t.add_argument("--masked", action=argparse.BooleanOptionalAction,
                   default=_default(train_dictionaries, "masked"),
                   help="fit valid bins only (bins below the horizon and unmeasured bins "
                        "are free values); --no-masked fits them as zeros")
    t.add_argument("--init", default=_default(train_dictionaries, "init"), choices=TRAIN["init"],
                   help="initial clusters: seeded (k-means++ in the training error) or "
                        "random balanced")
    t.add_argument("--seed", type=_typed(TRAIN["seed"]), default=_default(train_ensemble, "seed"),
                   help="seed of the initial clusters: the same seed gives the same ensemble")
    t.add_argument("--grid", nargs=3, type=_typed(GRID_SIDE),
                   default=_default(training_data, "shape"), metavar=("N_H", "N_D", "N_P"),
                   help="the tensors' grid (theta_h, theta_d, phi_d bins)")
    t.add_argument("--checkpoint-dir", help="checkpoint every iteration here and resume "
                                            "(default: no checkpoints)")
    t.add_argument("--extend", help="unite the new dictionaries with this ensemble (default: "
                                    "a new ensemble of these alone)")
    t.add_argument("-o", "--output", required=True, help="output ensemble .npz")
    _add_where(t, "the per-tensor work of each iteration")
    t.set_defaults(func=cmd_train)


def _add_codec_commands(sub) -> None:
    """``encode`` and ``decode``."""
    e = sub.add_parser("encode", help="encode a BRDF as sparse coefficients (.sbrdf)",)
    e.add_argument("source", help="BRDF source (see below), or a folder or quoted glob "
                                  "of materials to encode them all (batch)")
    e.add_argument("-o", "--output", required=True,
                   help="output .sbrdf path; batch: output folder (<stem>.sbrdf per material, "
                        "summary.csv, summary.json; finished outputs are kept; exit status "
                        "1 if any material failed)")
    size = e.add_mutually_exclusive_group()
    size.add_argument("--coeffs", type=_typed(COEFFS), default=_default(encode, "n_coeffs"),
                      action=_Given,
                      help="the coefficient budget N. With the joint budget (--budget joint, "
                           "the default of the default --basis opponent) the file holds 3 x N "
                           "coefficients shared over the three coded channels where they "
                           "lower the error most, so one channel may hold more than N (e.g. "
                           "262 may give [475, 161, 150]); with --budget channel (--paper) at "
                           "most N per channel. Capped to a channel's entries on a small grid")
    size.add_argument("--bytes", type=_typed(budget_module.PARAMETERS["n_bytes"]),
                      default=_default(encode_to_bytes, "n_bytes"), metavar="N",
                      help="byte budget instead: the .sbrdf file holds at most N bytes "
                           "(header included), the coefficients kept the largest over the "
                           "channels (docs/file-format.md, Byte budgets; default: --coeffs)")
    e.add_argument("--max-error", type=_typed(ENCODE["max_error"]),
                   default=_default(encode, "max_error"),
                   help="stop adding coefficients once the relative squared residual in the "
                        "transformed domain is below this (e.g. 1e-4; default: never, the "
                        "budget decides)")
    e.add_argument("--transform", default=_default(encode, "transform"),
                   choices=ENCODE["transform"],
                   help="auto: the one --selector prefers")
    e.add_argument("--selector", default=_default(encode, "selector"),
                   choices=ENCODE["selector"],
                   help="how auto picks the transform: the smaller render-proxy error, or "
                        "the smaller gamma-mapped MSE (the paper's)")
    e.add_argument("--fill", default=_default(encode, "fill"), choices=ENCODE["fill"],
                   help="bins filled from the model instead of fitted as zeros: every "
                        "invalid bin, or only unmeasured bins above the horizon")
    e.add_argument("--fill-iters", type=_typed(ENCODE["fill_iters"]),
                   default=_default(encode, "fill_iters"),
                   help="fill rounds (0: no fill; default per --fill: "
                        + ", ".join(f"{k} {v}" for k, v in DEFAULT_FILL_ITERS.items()) + ")")
    e.add_argument("--basis", default=_default(encode, "basis"), choices=ENCODE["basis"],
                   help="colour basis of the coded channels (opponent: luminance and two "
                        "colour differences)")
    e.add_argument("--paper", action="store_true",
                   help="the paper's model: --selector gamma-mse --fill missing --basis rgb, "
                        "over the shipped ensemble trained for the paper's transforms unless "
                        "--ensemble names another")
    _add_symmetrize(e)
    e.add_argument("--budget", default=_default(encode, "budget"), choices=ENCODE["budget"],
                   help="--coeffs per channel, or 3 x --coeffs over the channels "
                        "(default: joint for --basis opponent, else channel)")
    e.add_argument("--ensemble", help="ensemble .npz (default: the shipped default)")
    e.add_argument("--json", action="store_true", help="print the encoding statistics as JSON")
    _add_where(e, "a batch")
    _add_source_help(e)
    e.set_defaults(func=cmd_encode, coeffs_given=False)

    _add_samples_commands(sub)

    d = sub.add_parser("decode", help="decode a .sbrdf file to a MERL .binary file")
    d.add_argument("source", help=".sbrdf file")
    d.add_argument("-o", "--output", required=True, help="output .binary path")
    d.add_argument("--ensemble", help="ensemble .npz (default: the shipped one the file names)")
    d.set_defaults(func=cmd_decode)


def _add_samples_commands(sub) -> None:
    """``encode-samples`` and ``plan-samples``."""
    acq = acquire_module.PARAMETERS
    es = sub.add_parser(
        "encode-samples", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="encode measured samples (direction pairs and RGB values) as a .sbrdf",
        description="Compressed sensing with the ensemble's dictionaries (docs/method.md, "
                    "Encoding from samples): per coded channel a sparse fit through the "
                    "sampling operator (atoms interpolated between the bins) over the "
                    "atoms training materials use, toward their training values; the "
                    "support size, dictionary and transform chosen by cross-validation on "
                    "held-out samples. SAMPLES is a CSV with the header "
                    "wi_x,wi_y,wi_z,wo_x,wo_y,wo_z,r,g,b[,weight] or an .npz with arrays "
                    "wi, wo, rgb[, weight]: unit directions in the local frame (z the "
                    "normal), linear RGB in 1/sr. Repeated pairs count as repeated "
                    "measurements.",
        epilog="example:\n  sparse-brdf plan-samples 2000 -o plan.csv\n  (measure, fill in "
               "r,g,b)\n  sparse-brdf encode-samples plan.csv -o material.sbrdf")
    es.add_argument("samples", help="samples file (.csv or .npz)")
    es.add_argument("-o", "--output", required=True, help="output .sbrdf (written atomically)")
    budget = es.add_mutually_exclusive_group()
    budget.add_argument("--coeffs", type=_typed(acq["n_coeffs"].capped(GRID_BINS.hi)),
                        default=_default(acquire_module.encode_samples, "n_coeffs"),
                        help="the coefficient budget N: a joint budget of 3 x N shared over "
                             "the three coded channels (one channel may hold more than N), "
                             "fewer when held-out samples say more would overfit (default "
                             "%(default)s)")
    budget.add_argument("--bytes", type=_typed(budget_module.PARAMETERS["n_bytes"]),
                        default=_default(acquire_module.encode_samples, "n_bytes"),
                        metavar="N", help="the file holds at most N bytes (default: --coeffs)")
    es.add_argument("--ensemble", help="ensemble .npz or id (default: the shipped default)")
    es.add_argument("--seed", type=_typed(acq["seed"]),
                    default=_default(acquire_module.encode_samples, "seed"),
                    help="seed of the cross-validation folds (default %(default)s)")
    es.add_argument("--prior", choices=PRIORS,
                    default=_default(encode_samples_file, "prior"),
                    help="default: each dictionary restricted to the atoms the training "
                         "split's materials use, fitted toward their values (computed once "
                         "and cached; needs the merl data); none: every atom, no prior "
                         "(default %(default)s)")
    es.set_defaults(func=cmd_encode_samples)

    ps = sub.add_parser(
        "plan-samples", help="write direction pairs to measure, as a samples CSV with zero values",
        description="uniform: each direction uniform over the hemisphere; stratified: "
                    "strata of the grid's coordinates (dense near the specular peak); "
                    "bins: random valid bins at their lower-edge angles.")
    ps.add_argument("n", type=_typed(PLAN_PAIRS), help="direction pairs")
    ps.add_argument("-o", "--output", required=True,
                    help="output samples file: .csv (or .npz)")
    ps.add_argument("--placement", default=_default(plan, "placement"), choices=PLACEMENTS,
                    help="where the pairs lie (see above)")
    ps.add_argument("--seed", type=_typed(acq["seed"]), default=_default(plan, "seed"),
                    help="the same seed gives the same pairs")
    ps.set_defaults(func=cmd_plan_samples)


def _add_render(sub) -> None:
    r = sub.add_parser(
        "render", help="render a Mitsuba scene with materials overridden",
        description="Render any Mitsuba 3 scene file with some of its BSDFs (by id) replaced "
                    "by measured materials. spp, seed and the resolution fill the scene's "
                    "$spp, $seed and $res where it declares them, and are set on its "
                    "sampler and film otherwise; a scene's other parameters are set with -D.",
        epilog="examples:\n  sparse-brdf convert mitsuba:au-ggx-0.08 gold.binary\n"
               "  sparse-brdf encode gold.binary -o gold.sbrdf\n"
               "  sparse-brdf render sphere -o ref.exr --material material=gold.binary "
               f"--sampling {SHARED_PATHS}\n"
               "  sparse-brdf render sphere -o model.exr --material material=gold.sbrdf "
               f"--sampling {SHARED_PATHS} --mask mask.exr\n"
               "  sparse-brdf snr ref.exr model.exr --mask mask.exr\n"
               "  sparse-brdf render sphere -o look.png --material material=gold.sbrdf "
               "--exposure 1")
    r.add_argument("scene", help="scene XML: any Mitsuba 3 scene file, or the name of a "
                                 "shipped scene (sphere, spheres, sphere_light, paper_sphere)")
    r.add_argument("-o", "--output", required=True,
                   help="output image: .exr (linear HDR, float32) or .png/.jpg (an 8-bit "
                        "sRGB preview, see --exposure)")
    r.add_argument("--material", action="append", default=[], metavar="ID=FILE",
                   help="replace BSDF ID: a .sbrdf selects sparse_brdf, any other BRDF "
                        "source tabulated_brdf (repeatable; default: none, the scene as it "
                        "is)")
    r.add_argument("-D", "--define", action="append", default=[], metavar="KEY=VALUE",
                   help="set a parameter the scene declares, e.g. -D envrot=90 (repeatable; "
                        "default: the scene's values)")
    r.add_argument("--spp", type=_typed(RENDER["spp"]), default=_default(render_scene, "spp"),
                   help="samples per pixel")
    r.add_argument("--seed", type=_typed(RENDER["seed"]), default=_default(render_scene, "seed"),
                   help="the sampler's seed: the same seed and spp give the same image")
    r.add_argument("--res", type=_typed(RENDER["res"]), default=_default(render_scene, "res"),
                   help="the film's longer side in pixels, its aspect ratio kept (the "
                        "scene's $res where it declares one; default: the scene's film)")
    r.add_argument("--exposure", type=_typed(Interval(float, -64.0, 64.0)), default=0.0,
                   metavar="STOPS",
                   help="a .png/.jpg preview's exposure: values times 2^STOPS before the "
                        "sRGB curve (an .exr is written as rendered)")
    r.add_argument("--sampling", default=PLUGIN_DEFAULTS["sampling"], choices=SAMPLING,
                   help="BSDF sampling of the replaced materials: lobe (the plugins' "
                        "default) follows each material's highlight, the lower noise for "
                        f"looking at an image; {SHARED_PATHS} gives every material the same "
                        "sample paths for one seed and spp, so renders to compare (snr) "
                        "share their noise")
    r.add_argument("--decoder", default=PLUGIN_DEFAULTS["decoder"], choices=DECODERS,
                   help="how the sparse_brdf plugin evaluates .sbrdf materials: grouped "
                        "tables (fastest), strict (a loop over the terms: least memory), or "
                        "auto: grouped "
                        "unless its tables would be too large")
    r.add_argument("--ensemble", help="ensemble .npz for .sbrdf materials "
                   "(default: the shipped one each file names)")
    r.add_argument("--mask", metavar="MASK.exr",
                   help="also write the object mask (.exr or .npy; 1 where camera rays first "
                        "hit a shape of a replaced material), for `sparse-brdf snr --mask` "
                        "(default: none)")
    r.set_defaults(func=cmd_render)


def _add_snr(sub) -> None:
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


def _add_fit_scene(sub) -> None:
    fs = sub.add_parser("fit-scene", help="give each material of a scene the fewest "
                                          "coefficients that reach a target rendering SNR "
                                          "in that scene")
    fs.add_argument("scene", help="scene XML: any Mitsuba 3 scene file, or the name of a "
                                  "shipped scene")
    fs.add_argument("--target-snr", type=_typed(Interval(float)), required=True, metavar="DB",
                    help="the object-only rendering SNR each material must reach (the "
                         "object: the shapes of the fitted materials)")
    fs.add_argument("--material", action="append", default=[], metavar="ID=FILE",
                    help="measured material of BSDF ID (repeatable); tabulated_brdf BSDFs "
                         "with a filename in the XML are found by themselves")
    fs.add_argument("-o", "--output", default=_default(fit_scene, "out"),
                    help="output folder (a .sbrdf per material and fit-scene.md)")
    fs.add_argument("--spp", type=_typed(RENDER["spp"]), default=_default(fit_scene, "spp"),
                    help="spp of the verification renders")
    fs.add_argument("--res", type=_typed(RENDER["res"]), default=_default(fit_scene, "res"),
                    help="the verification renders' longer side in pixels (aspect ratio "
                         "kept; the scene's $res where it declares one)")
    fs.add_argument("--seed", type=_typed(RENDER["seed"]), default=_default(fit_scene, "seed"),
                    help="seed of the verification renders (reference and models share it, "
                         f"with {SHARED_PATHS} sampling)")
    fs.add_argument("--bytes", type=_typed(budget_module.PARAMETERS["n_bytes"]),
                    default=_default(fit_scene, "max_bytes"), metavar="N",
                    help="per material: no .sbrdf file holds more than N bytes (the ladder "
                         "of budgets ends at the largest coefficients that fit; default: no "
                         "limit)")
    fs.add_argument("--ensemble", help="ensemble .npz (default: the shipped one)")
    fs.set_defaults(func=cmd_fit_scene)


def _add_fit_images(sub) -> None:
    fi = sub.add_parser(
        "fit-images",
        help="fit a .sbrdf's coefficient values to reference images (inverse rendering)",
        description="Optimise the coefficient values of START (its support is kept) so "
                    "that renders of SCENE match the reference images, with Mitsuba's "
                    "Adam through the plugin's differentiable values (docs/fit-images.md)."
                    " Each --view is an EXR image and the scene defaults it was taken "
                    "with, e.g. ref.exr:envrot=90 or ref.exr:envmap=forest.exr,envrot=90,"
                    "envtilt=30; each image's size sets the film's. The fit renders with "
                    f"{SHARED_PATHS} sampling: render the references with --sampling "
                    f"{SHARED_PATHS}, the fit's --seed and --spp.")
    fi.add_argument("scene", help="scene XML (a path, or a name in the shipped scenes/)")
    fi.add_argument("--view", action="append", required=True, metavar="IMAGE.exr[:K=V,...]",
                    help="a reference image and its scene defaults (repeatable)")
    fi.add_argument("--start", required=True, metavar="FILE.sbrdf",
                    help="the starting coefficients (their dictionaries and atoms are kept)")
    fi.add_argument("-o", "--output", required=True, metavar="OUT.sbrdf",
                    help="the fitted .sbrdf (checked writable before the fit)")
    fi.add_argument("--material", default=_default(fit_images, "material"),
                    help="id of the scene's BSDF that the model replaces")
    fip = fit_images_module.PARAMETERS
    fi.add_argument("--iterations", type=_typed(fip["iterations"]),
                    default=_default(fit_images, "iterations"),
                    help="optimiser iterations (evaluations of the loss)")
    fi.add_argument("--optimizer", choices=fit_images_module.OPTIMIZERS,
                    default=_default(fit_images, "optimizer"),
                    help="adam, or lbfgs (L-BFGS-B on the shared-path loss; --iterations "
                         "then counts its evaluations, --lr and --lr-end are not used)")
    fi.add_argument("--loss", choices=fit_images_module.LOSSES,
                    default=_default(fit_images, "loss"),
                    help="relative: the views' mean relative squared error; log: its "
                         "mean logarithm (the views' mean SNR in dB)")
    fi.add_argument("--prior-weight", type=_typed(fip["prior_weight"]),
                    default=_default(fit_images, "prior_weight"),
                    help="weight (>= 0) of a penalty W * mean(((value - start) / scale)^2) "
                         "on the values' change relative to the start (scale: each "
                         "value's starting magnitude, floored at 1e-3 of its channel's "
                         "largest); the relative loss is a relative squared error (1e-4 "
                         "at 40 dB), so useful weights are small, e.g. 1e-6 to 1e-4; with "
                         "--loss log 1 dB is 0.23 of the loss, so weights are larger; 0 "
                         "(the default): the views alone")
    fi.add_argument("--validation-view", action="append", metavar="IMAGE.exr[:K=V,...]",
                    help="a reference never fitted, as --view: every --validate-every "
                         "evaluations the fit renders these, and writes the iterate they "
                         "match best (early stopping; repeatable; default: none, the last "
                         "iterate is written)")
    fi.add_argument("--validate-every", type=_typed(fip["validate_every"]),
                    default=_default(fit_images, "validate_every"),
                    help="evaluations (iterations) between two validations")
    fi.add_argument("--lr", type=_typed(fip["lr"]), default=_default(fit_images, "lr"),
                    help="Adam's first learning rate, a relative step per value")
    fi.add_argument("--lr-end", type=_typed(fip["lr_end"]),
                    default=_default(fit_images, "lr_end"),
                    help="the last iteration's rate as a fraction of --lr (geometric decay)")
    fi.add_argument("--spp", type=_typed(fip["spp"]), default=_default(fit_images, "spp"),
                    help="samples per pixel of each render (use the references' spp)")
    fi.add_argument("--seed", type=_typed(RENDER["seed"]), default=_default(fit_images, "seed"),
                    help="the references' seed: the fit's renders share their sample paths "
                         f"(render the references with --sampling {SHARED_PATHS})")
    fi.add_argument("--checkpoint-dir", default=None,
                    help="keep fit-images.npz here; a rerun resumes from it (default: no "
                         "checkpoint)")
    fi.add_argument("--decoder", choices=DECODERS, default=_default(fit_images, "decoder"),
                    help="the sparse_brdf plugin's decoder of the fit's renders")
    fi.add_argument("--variant", default=_default(fit_images, "variant"),
                    help="a differentiable Mitsuba variant (llvm_ad_*, cuda_ad_*)")
    fi.add_argument("--ensemble", help="ensemble .npz (default: the shipped one)")
    fi.set_defaults(func=cmd_fit_images)


def _add_blend_and_bench(sub) -> None:
    """``blend`` and ``bench``."""
    bl = sub.add_parser("blend", help="interpolate two .sbrdf materials in coefficient space")
    bl.add_argument("a", help="first .sbrdf (its dictionaries and transform are used)")
    bl.add_argument("b", help="second .sbrdf (same ensemble and transform)")
    bl.add_argument("--alpha", type=_typed(INTERPOLATE["alpha"]), required=True,
                    help="0 gives A, 1 gives B")
    bl.add_argument("--coeffs", type=_typed(INTERPOLATE["n_coeffs"].capped(GRID_BINS.hi)),
                    default=_default(interpolate, "n_coeffs"), action=_Given,
                    help="at most this many coefficients per channel of the result "
                         "(default: the larger of the two files' counts)")
    bl.add_argument("--ensemble", help="ensemble .npz (default: the shipped one the files name)")
    bl.add_argument("-o", "--output", required=True, help="output .sbrdf")
    bl.set_defaults(func=cmd_blend, coeffs_given=False)

    b = sub.add_parser("bench", help="compare models: tables, figures, speed-vs-accuracy chart",
                       description="Run a bench suite: a built-in config by name ("
                                   + ", ".join(shipped_configs()) + ") or a TOML file; "
                                   "finished cells are skipped on a re-run. `acquisition` "
                                   "(or a config with bench = \"acquisition\") benches "
                                   "encoding from N measured samples, the sparse model against "
                                   "PCA (docs/results.md); it renders every fit and takes "
                                   "neither --no-render nor a Dask cluster.")
    b.add_argument("config", nargs="?",
                   help="a built-in config's name or a TOML file (default: the small suite)")
    b.add_argument("--out", help="output folder (default: the config's)")
    b.add_argument("--no-render", action="store_true", help="BRDF-space metrics only")
    b.add_argument("--model", action="append", metavar="SPEC",
                   help="compare this model instead of the config's models (repeat it for "
                        "several): a built-in spec (sparse:262, naive, pca:40, tabulated, "
                        "...) or module:Class[:KEY=VALUE,...], a class of your own imported "
                        "from the Python path or the current directory "
                        "(docs/bench-guide.md; default: the config's models)")
    b.add_argument("--check", action="store_true",
                   help="check the config (settings, models, corpora, training materials, "
                        "scenes) and exit without running it")
    _add_where(b, "the cells (material x model)")
    b.set_defaults(func=cmd_bench)

    bm = sub.add_parser("bench-merge", help="rank the models of several bench results in "
                                            "one table (Markdown and CSV)",
                        description="Merge results.json files of benches that measured "
                                    "the same protocol (corpora, split, scenes, spp, res, "
                                    "seed), e.g. the standard suite's shipped models and "
                                    "your own model's run, from any machines, into one "
                                    "ranked table: ranking.md and ranking.csv.")
    bm.add_argument("results", nargs="+", help="results.json files or bench output folders")
    bm.add_argument("--by", choices=tuple(RANK_BY), default=_default(merge_results, "by"),
                    help="rank by the mean over the scenes of this figure (higher SNR, "
                         "lower HDR-FLIP first)")
    bm.add_argument("-o", "--output", required=True, help="output folder")
    bm.set_defaults(func=cmd_bench_merge)


#: Exit status of an internal error (a bug), as sysexits.h's EX_SOFTWARE.
EXIT_BUG = 70


def _describe(exc: BaseException) -> str:
    """The message of an expected error; an OSError names its file."""
    if isinstance(exc, OSError) and not isinstance(exc, SparseBRDFError) and exc.filename:
        names = f"{exc.filename}" + (f" -> {exc.filename2}" if exc.filename2 else "")
        return f"{names}: {exc.strerror or exc}"
    return str(exc) or type(exc).__name__


def _no_madvised_hugepages() -> None:
    """Stop numpy asking the kernel for transparent huge pages for its large arrays, unless
    ``NUMPY_MADVISE_HUGEPAGE`` says otherwise (numpy's own switch, read at its import).

    A command is a short process whose large arrays are all freshly mapped memory; where
    the kernel compacts memory to serve huge pages on request (``defrag`` of ``madvise``,
    a common default) those first touches stall. On the 2-core benchmark machine this
    made a whole ``encode`` 2-8 % slower (docs/benchmarks.md, "Whole commands after
    cutting fixed costs"). Only the
    command line does this: a program that imports the library keeps numpy's setting."""
    if "NUMPY_MADVISE_HUGEPAGE" in os.environ:
        return
    setter = getattr(getattr(np, "_core", None), "multiarray", None)
    setter = getattr(setter, "_set_madvise_hugepage", None)
    if setter is not None:
        setter(False)


#: glibc ``mallopt`` settings of a command: (parameter number, value, the environment
#: variables that set it instead). Freed arrays below 32 MB stay in the heap, and the heap
#: is not returned to the system below 1 GB of free space at its top, so a command's
#: large arrays reuse memory already touched instead of mapping fresh pages each time.
MALLOC_SETTINGS = ((-3, 32 << 20, "MALLOC_MMAP_THRESHOLD_"),  # M_MMAP_THRESHOLD
                   (-1, 1 << 30, "MALLOC_TRIM_THRESHOLD_"))   # M_TRIM_THRESHOLD


def _malloc_settings(environ: Mapping[str, str]) -> list[tuple[int, int]]:
    """The :data:`MALLOC_SETTINGS` to apply: none where the user tunes glibc's malloc
    (``GLIBC_TUNABLES`` naming ``glibc.malloc``), else each one its own variable does not
    set."""
    if "glibc.malloc" in environ.get("GLIBC_TUNABLES", ""):
        return []
    return [(param, value) for param, value, var in MALLOC_SETTINGS if var not in environ]


def _keep_freed_memory() -> None:
    """Apply :func:`_malloc_settings` through glibc's ``mallopt`` (Linux with glibc; a
    no-op elsewhere). On the 2-core benchmark machine this made a whole ``encode`` 4-7 %
    faster (docs/benchmarks.md, "Whole commands after cutting fixed costs")."""
    if not sys.platform.startswith("linux"):
        return
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return
    for param, value in _malloc_settings(os.environ):
        mallopt(ctypes.c_int(param), ctypes.c_int(value))


def main(argv: list[str] | None = None) -> int:
    """Run one command. Exit status: 0 done; 2 a bad input, option or output (one line on
    stderr naming it); 70 an internal error (a bug); 128 + N killed by signal N (SIGINT,
    SIGTERM, SIGHUP), no partial output left. ``--debug`` (anywhere) or
    ``SPARSE_BRDF_DEBUG=1`` adds the traceback and numpy's warnings."""
    argv = list(sys.argv[1:] if argv is None else argv)
    _no_madvised_hugepages()
    _keep_freed_memory()
    debug = "--debug" in argv or os.environ.get("SPARSE_BRDF_DEBUG", "") not in ("", "0")
    args = build_parser().parse_args([a for a in argv if a != "--debug"])
    with warnings.catch_warnings(), cleanup_on_signals():
        if not debug:  # overflow etc. in numpy: the results are checked instead
            warnings.simplefilter("ignore", RuntimeWarning)
        try:
            return int(args.func(args) or 0)
        except KeyboardInterrupt as exc:  # SIGINT, or SIGTERM/SIGHUP (errors.Interrupted)
            remove_temporaries()
            signum = int(getattr(exc, "signum", signal.SIGINT))
            _report(debug, f"interrupted by {signal.Signals(signum).name}; no partial "
                           "output was left")
            return 128 + signum
        except BrokenPipeError:  # the reader of stdout went away (`... | head`): quietly
            with contextlib.suppress(OSError):
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 128 + signal.SIGPIPE
        except (SparseBRDFError, OSError) as exc:
            _report(debug, f"error: {_describe(exc)}")
            return 2
        except MemoryError:  # a size the options ask for that this machine cannot hold
            _report(debug, "error: not enough memory for what the options ask (a size, "
                           "count or resolution too large for this machine); no output "
                           "was written")
            return 2
        except Exception as exc:  # noqa: BLE001 - anything else is a bug, said so
            _report(debug, f"internal error (a bug, please report it): "
                           f"{type(exc).__name__}: {exc}; run with --debug or "
                           "SPARSE_BRDF_DEBUG=1 for the traceback")
            return EXIT_BUG


def _report(debug: bool, message: str) -> None:
    """Print ``message`` as one line on stderr, after the traceback with ``debug``."""
    if debug:
        traceback.print_exc()
    print(f"sparse-brdf: {one_line(message)}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
