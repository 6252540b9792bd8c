"""Fit a material's coefficient values to images: inverse rendering on a fixed support.

:func:`fit_images` takes a scene, reference images of a material in that scene under
known lighting and views (:class:`View`: an image and the scene defaults it was taken
with, e.g. ``{"envrot": "90"}`` or ``{"envmap": "forest.exr", "envtilt": "30"}``: each
view may carry its own map), and a starting ``.sbrdf``. It keeps the starting
file's support (its dictionaries and atoms) and optimises the coefficient values of the
three coded channels with Mitsuba's Adam (``mi.ad.Adam``) or SciPy's L-BFGS-B
(``optimizer="lbfgs"``: the shared-path loss is a smooth deterministic function of the
values, and a quasi-Newton method converges in far fewer renders), differentiating the renders
through the ``sparse_brdf`` plugin's ``values_0`` .. ``values_2`` parameters
(``docs/fit-images.md``). The loss is the mean over views of the relative squared error
``sum (img - ref)^2 / sum ref^2``, so its ``-10 log10`` is the views' mean whole-image
rendering SNR.

Each value is optimised as ``scale * u`` with ``scale`` its starting magnitude (floored at
1e-3 of its channel's largest): Adam's steps are then relative, the same for the large
low-order coefficients and the small high-order ones. Optionally a penalty on ``u``'s
change from the start (``prior_weight``) joins the loss, and validation views that are
never optimised pick the iterate the fit returns (``validation``: early stopping).
The primal renders use the references' seed (the same sample paths when the references
were rendered by Mitsuba with that seed); each gradient pass uses a fresh seed, as
Mitsuba requires.

Mitsuba and Dr.Jit are imported inside the functions, so importing this module stays
fast; the scenes are loaded through :func:`sparse_brdf.evaluation.render.load_scene`.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..coding.coefficients import SparseBRDF
from ..coding.ensemble import Ensemble, resolve_ensemble
from ..coding.fileformat import load_sbrdf, save_sbrdf
from ..errors import ImageFileError, RenderError, SparseBRDFError, UsageError
from ..evaluation.render import SHARED_PATHS, load_scene
from ..evaluation.scenes import parse_defaults, parse_scene
from ..mitsuba_env import DEFAULT_VARIANT
from ..params import Interval, check
from ._steps import (
    VALUE_KEYS,
    FitScene,
    Monitor,
    read_checkpoint,
    run_lbfgs,
    take_step,
    write_checkpoint,
)

#: Defaults of the fit: iterations, Adam's first learning rate, its last as a fraction of
#: the first (the rate falls geometrically in between), samples per pixel.
DEFAULT_ITERATIONS, DEFAULT_LR, DEFAULT_LR_END, DEFAULT_SPP = 150, 0.02, 0.1, 4
#: The fit's numeric options and their ranges (the CLI takes its bounds from here).
PARAMETERS = {"iterations": Interval(int, 1, 1 << 20), "lr": Interval(float, 0, 10, "right"),
              "lr_end": Interval(float, 0, 1, "right"), "spp": Interval(int, 1, 1 << 16),
              "prior_weight": Interval(float, 0, 1e6), "validate_every": Interval(int, 1, 1 << 20)}
#: The optimisers of :func:`fit_images`.
OPTIMIZERS = ("adam", "lbfgs")
#: The losses of :func:`fit_images` (see its ``loss`` parameter).
LOSSES = ("relative", "log")
#: A value's scale is at least this fraction of its channel's largest magnitude.
SCALE_FLOOR = 1e-3


@dataclass
class View:
    """One reference image (float32 (H, W, 3), linear) and the scene defaults it was
    rendered or photographed with (e.g. ``{"envrot": "90"}``)."""

    image: np.ndarray
    params: dict = field(default_factory=dict)
    name: str = "view"
    #: The seed the reference was rendered with (None: the fit's ``seed``). Views of
    #: several seeds sample the material at more directions, each still along its
    #: reference's own sample paths.
    seed: int | None = None


@dataclass
class FitResult:
    """The fitted model and the fit's record: per iteration the views' mean whole-image
    SNR (dB) of the values before that iteration's step; wall-clock seconds."""

    model: SparseBRDF
    snr_db: list[float]
    seconds: float
    seconds_per_iteration: float
    iterations: int
    resumed_from: int = 0
    #: With validation views: (evaluations done, the validation views' SNR in dB, in the
    #: form of the loss: of their mean relative squared error, or with ``loss="log"``
    #: their mean SNR) of each validated iterate, in order.
    validation_snr_db: list[tuple[int, float]] = field(default_factory=list)
    #: With validation views: the evaluation count of the returned iterate (the one the
    #: validation views liked best); None without them.
    best_evaluation: int | None = None

    def summary(self) -> dict:
        return {"iterations": self.iterations, "seconds": round(self.seconds, 2),
                "seconds_per_iteration": round(self.seconds_per_iteration, 3),
                "start_snr_db": self.snr_db[0] if self.snr_db else None,
                "final_snr_db": self.snr_db[-1] if self.snr_db else None,
                "resumed_from": self.resumed_from,
                "best_evaluation": self.best_evaluation}


def parse_view(text: str, option: str = "--view") -> tuple[str, dict]:
    """``IMAGE.exr[:KEY=VALUE[,KEY=VALUE...]]`` -> (image path, scene defaults); an error
    names ``option``."""
    path, sep, tail = str(text).rpartition(":")
    if not sep or "=" not in tail:
        return str(text), {}
    params = parse_defaults(tail.split(","), f"{option} {text!r}:")
    return path, params


def check_view_params(scene, params: Mapping[str, object], where: str) -> None:
    """A :class:`UsageError` naming ``where`` (e.g. ``--view ref.exr:envrot=90``) when a
    view sets a key that is not one of the scene's ``<default>`` names (a view may set
    any of them, e.g. ``envmap``, ``envrot`` and ``envtilt`` in ``sphere.xml``)."""
    names = {d.get("name") for d in parse_scene(scene).getroot().iter("default")}
    unknown = sorted(set(params) - names)
    if unknown:
        raise UsageError(f"{where}: {', '.join(unknown)} is not a default of "
                         f"{Path(scene).name} (it has {', '.join(sorted(names))})")


def _fingerprint(scene, views: Sequence[View], model: SparseBRDF, settings: dict) -> str:
    """A hash of what a checkpoint belongs to: scene, views, start values, settings."""
    h = hashlib.sha256(str(Path(scene).resolve()).encode())
    for v in views:
        h.update(np.ascontiguousarray(v.image, np.float32).tobytes())
        h.update(json.dumps(v.params, sort_keys=True).encode())
        if v.seed is not None:
            h.update(f"seed={int(v.seed)}".encode())
    for a in model.values:
        h.update(np.ascontiguousarray(a, np.float32).tobytes())
    h.update(json.dumps(settings, sort_keys=True).encode())
    return h.hexdigest()[:16]


def _value_keys(params, material: str) -> list[str]:
    """The three ``mi.traverse`` keys of the material's values."""
    keys = []
    for k in VALUE_KEYS:
        found = [p for p in params.keys() if p.endswith("." + k) or p == k]
        own = [p for p in found if p.split(".")[0] == material]
        if len(own) == 1 or len(found) == 1:
            keys.append((own or found)[0])
        else:
            raise UsageError(f"material {material!r}: found {len(found)} sparse_brdf "
                             f"parameters {k} in the scene ({', '.join(found) or 'none'})")
    return keys


def _load_views(scene, views, material, start_path, spp, seed, variant, options):
    import mitsuba as mi  # lazy: Mitsuba is slow to import (see the module doc)

    out = []
    for v in views:
        img = np.asarray(v.image, np.float32)
        if img.ndim != 3 or img.shape[2] != 3 or not np.isfinite(img).all():
            raise ImageFileError(f"{v.name}: a reference must be a finite RGB image, got "
                                 f"shape {img.shape}")
        res = (img.shape[1], img.shape[0])  # the film takes the reference's size
        check_view_params(scene, v.params, v.name)
        try:
            vseed = seed if v.seed is None else int(v.seed)
            sc = load_scene(scene, {material: str(start_path)}, spp=spp, seed=vseed, res=res,
                            variant=variant, params=v.params, sparse_options=options,
                            sampling=SHARED_PATHS)
        except SparseBRDFError as exc:  # e.g. a view's envmap that is not on this machine
            raise type(exc)(f"{v.name}: {exc}") from exc
        size = tuple(int(x) for x in sc.sensors()[0].film().crop_size())
        if size != (img.shape[1], img.shape[0]):
            raise ImageFileError(f"{v.name}: {img.shape[1]}x{img.shape[0]}, but the scene "
                                 f"renders {size[0]}x{size[1]}")
        params = mi.traverse(sc)
        norm = float(np.sum(np.square(img, dtype=np.float64)))
        if norm <= 0:
            raise ImageFileError(f"{v.name}: the reference image is black")
        out.append(FitScene(sc, params, _value_keys(params, material), mi.TensorXf(img), norm,
                          vseed))
    return out


def _check_request(views: Sequence[View], optimizer: str, loss: str, shared_paths: bool,
                   variant: str, **values) -> None:
    """Check a fit's request before any work (``values``: the ranged parameters by name);
    a :class:`~sparse_brdf.errors.UsageError` names what is wrong."""
    if not views:
        raise UsageError("fit-images: give at least one reference view")
    for name, value in values.items():
        check(name, value, PARAMETERS[name])
    if optimizer not in OPTIMIZERS:
        raise UsageError(f"fit-images: optimizer {optimizer!r}: use one of "
                         f"{', '.join(OPTIMIZERS)}")
    if loss not in LOSSES:
        raise UsageError(f"fit-images: loss {loss!r}: use one of {', '.join(LOSSES)}")
    if optimizer == "lbfgs" and not shared_paths:
        raise UsageError("fit-images: the lbfgs optimizer needs the shared-path loss "
                         "(shared_paths=True)")
    if "_ad_" not in variant:
        raise UsageError(f"fit-images: variant {variant!r} is not differentiable: use an "
                         "llvm_ad_* or cuda_ad_* variant")


def _start_model(start: str | os.PathLike | SparseBRDF,
                 ensemble: str | os.PathLike | Ensemble | None) -> SparseBRDF:
    """The fit's starting model: ``start`` itself, or the file read with its ensemble
    (``ensemble``, else the shipped one the file names)."""
    ens = ensemble if isinstance(ensemble, Ensemble) else None
    if isinstance(start, SparseBRDF):
        return start
    ens = ens or resolve_ensemble(ensemble, for_id=load_sbrdf(start).ensemble_id)
    return load_sbrdf(start, ens)


def _settings(*, lr, lr_end, spp, seed, material, decoder, variant, shared_paths,
              optimizer, loss, prior_weight, validation, validate_every) -> dict:
    """The settings a checkpoint's fingerprint covers; those at their defaults (optimizer,
    loss, prior, validation) are left out, so older checkpoints still resume."""
    return {"lr": lr, "lr_end": lr_end, "spp": spp, "seed": seed, "material": material,
            "decoder": decoder, "variant": variant, "shared_paths": shared_paths,
            **({"optimizer": optimizer} if optimizer != "adam" else {}),
            **({"loss": loss} if loss != "relative" else {}),
            **({"prior_weight": prior_weight} if prior_weight else {}),
            **({"validation": validation, "validate_every": validate_every}
               if validation else {})}


def _scaled_optimizer(model: SparseBRDF, lr: float) -> tuple:
    """Mitsuba's Adam over the relative values ``u = value / scale`` of each coded channel
    (``scale``: the value's starting magnitude, floored at ``SCALE_FLOOR`` of its
    channel's largest); returns ``(opt, scales, u0)``, ``u0`` the start's relative values
    (1, or less below the floor), the prior's centre, float64 of shape (total values,)."""
    import drjit as dr  # lazy: Mitsuba and Dr.Jit are slow to import (see the module doc)
    import mitsuba as mi

    scales = []
    opt = mi.ad.Adam(lr=lr)
    for c, key in enumerate(VALUE_KEYS):
        v = np.asarray(model.values[c], np.float32)
        top = float(np.max(np.abs(v))) if v.size else 1.0
        s = np.maximum(np.abs(v), SCALE_FLOOR * max(top, 1e-30)).astype(np.float32)
        scales.append(mi.Float(s))
        opt[key] = mi.Float((v / s).astype(np.float32))
    u0 = np.concatenate([np.array(dr.detach(opt[k]), np.float64) for k in VALUE_KEYS])
    return opt, scales, u0


def _plugin_options(decoder: str, ensemble: str | os.PathLike | Ensemble | None,
                    tmp: Path) -> dict:
    """The ``sparse_brdf`` plugin's options for the fit's renders: the decoder and, when
    one is given, the ensemble's file (an in-memory ensemble saved into ``tmp``)."""
    ens_path = None
    if ensemble is not None:
        ens_path = (str(ensemble) if not isinstance(ensemble, Ensemble)
                    else str(ensemble.save(tmp / "ensemble.npz")))
    return {"decoder": decoder, **({"ensemble": ens_path} if ens_path else {})}


def _values(opt, scales: list) -> list[np.ndarray]:
    """The coded channels' values at the optimiser's current relative values ``u``:
    ``u * scale``, float32 of shape (T_c,) each."""
    import drjit as dr  # lazy: Mitsuba and Dr.Jit are slow to import (see the module doc)

    return [np.array(dr.detach(opt[k] * s), np.float32)
            for k, s in zip(VALUE_KEYS, scales, strict=True)]


def _resume(checkpoint_dir: str | os.PathLike | None, opt, fp: str,
            monitor: Monitor) -> tuple[Path | None, int, list]:
    """``(checkpoint file, iterations done, SNR per iteration so far)``: resumed from
    ``checkpoint_dir``'s checkpoint of this fit (``fp``) when there is one (the
    optimiser's values and the monitor restored), else from the start."""
    ckpt = Path(checkpoint_dir) / "fit-images.npz" if checkpoint_dir else None
    done, snr = 0, []
    if ckpt is not None and ckpt.is_file():
        done, snr, data = read_checkpoint(ckpt, opt, fp)
        monitor.restore(data, done)
    elif ckpt is not None:
        ckpt.parent.mkdir(parents=True, exist_ok=True)
    return ckpt, done, snr


def _run_lbfgs(scene, *args) -> None:
    """:func:`~sparse_brdf.fitting._steps.run_lbfgs` with ``args``; a render that fails
    is a :class:`~sparse_brdf.errors.RenderError` naming ``scene``."""
    try:
        run_lbfgs(*args)
    except RuntimeError as exc:
        raise RenderError(f"{scene}: rendering failed during the fit: {exc}") from exc


def _run_adam(scene, scenes, opt, scales, u0, current, monitor, bar, snr: list,
              steps: range, *, iterations, lr, lr_end, seed, spp, shared_paths, log,
              prior_weight, ckpt, checkpoint_every, fp) -> None:
    """Adam's iterations ``steps`` (each renders every view once and takes one step, at
    the learning rate falling geometrically from ``lr`` to ``lr * lr_end``), appending
    each one's SNR (dB) to ``snr``; the monitor, the bar and the checkpoint follow."""
    for it in steps:
        opt.set_learning_rate(lr * lr_end ** (it / max(iterations - 1, 1)))
        try:
            gseed = seed if shared_paths else seed + 1 + it * len(scenes)
            snr.append(take_step(scenes, opt, scales, seed, gseed, spp, log,
                                 prior_weight, u0))
            monitor(it + 1, current(), force=it + 1 == iterations)
        except RuntimeError as exc:
            raise RenderError(f"{scene}: rendering failed during the fit: "
                              f"{exc}") from exc
        bar.set_postfix(snr_db=f"{snr[-1]:.2f}")
        bar.update(1)
        if ckpt is not None and ((it + 1) % checkpoint_every == 0 or it + 1 == iterations):
            write_checkpoint(ckpt, it + 1, opt, snr, fp, monitor.state())


def fit_images(
    scene: str | os.PathLike,
    views: Sequence[View],
    start: str | os.PathLike | SparseBRDF,
    *,
    material: str = "material",
    ensemble: str | os.PathLike | Ensemble | None = None,
    iterations: int = DEFAULT_ITERATIONS,
    lr: float = DEFAULT_LR,
    lr_end: float = DEFAULT_LR_END,
    spp: int = DEFAULT_SPP,
    seed: int = 0,
    checkpoint_dir: str | os.PathLike | None = None,
    checkpoint_every: int = 10,
    decoder: str = "auto",
    variant: str = DEFAULT_VARIANT,
    shared_paths: bool = True,
    optimizer: str = "adam",
    loss: str = "relative",
    prior_weight: float = 0.0,
    validation: Sequence[View] = (),
    validate_every: int = 10,
    callback: Callable[[int, SparseBRDF], None] | None = None,
    progress: bool = True,
) -> FitResult:
    """Optimise the coefficient values of ``start`` so that renders of ``scene`` match
    the reference ``views``.

    Parameters
    ----------
    scene : path
        Any Mitsuba 3 scene XML whose BSDF ``material`` is replaced by the model (e.g. a
        shipped ``sphere.xml``); each reference's size sets the film of its view's render
        (any aspect ratio). The renders use cosine sampling (shared sample paths).
    views : sequence of View
        Reference images (float32 (H, W, 3), linear RGB) and the scene defaults of each.
    start : path or SparseBRDF
        The starting model: its support (dictionaries, atoms) is kept, its values are
        the starting point.
    material : str
        Id of the BSDF in the scene that the model replaces.
    ensemble : path, Ensemble or None
        The start file's ensemble (None: the shipped one it names).
    iterations, lr, spp, seed : int, float, int, int
        Adam iterations (each renders every view once and takes one step), Adam's
        learning rate (a relative step per value, see the module doc), samples per
        pixel, and the primal renders' seed (that of the references).
    lr_end : float
        The learning rate of the last iteration as a fraction of ``lr``, in (0, 1]; the
        rate falls geometrically from ``lr`` to ``lr * lr_end``, so that the values
        settle instead of jittering by about ``lr`` of themselves (docs/fit-images.md).
    checkpoint_dir : path or None
        Where to keep ``fit-images.npz`` (every ``checkpoint_every`` iterations): a rerun
        with the same inputs resumes from it; one of another fit is refused.
    decoder, variant : str
        The plugin's decoder and the Mitsuba variant (an ``*_ad_*`` one).
    shared_paths : bool
        Differentiate each view's render along the primal's own sample paths (seed
        ``seed``: the gradient of the very estimate the loss compares, low in variance;
        the default) or along fresh ones each iteration (Mitsuba's decorrelated,
        unbiased gradient, noisier at low spp).
    optimizer : str
        ``"adam"`` (Mitsuba's Adam with the learning-rate schedule; the default) or
        ``"lbfgs"`` (SciPy's L-BFGS-B on the shared-path loss, a smooth deterministic
        function of the values; ``iterations`` then counts its loss-and-gradient
        evaluations, each the cost of an Adam iteration, and ``lr``/``lr_end`` are not
        used; it needs ``shared_paths``). A checkpoint then holds the best values so
        far, and a resumed fit starts a fresh L-BFGS memory from them.
    loss : str
        ``"relative"``: the mean over the views of ``sum (img - ref)^2 / sum ref^2``
        (the default); ``"log"``: the mean of its logarithm, i.e. the views' mean SNR in
        dB, where a view already matched well still weighs as much as a poorly matched
        one. ``snr_db`` records the SNR of the loss used.
    prior_weight : float
        Weight (>= 0, dimensionless, like the loss) of a penalty
        ``prior_weight * mean(((value - start) / scale)^2)`` added to the loss, over all
        values, ``scale`` being each value's starting magnitude floored at 1e-3 of its
        channel's largest (the optimised ``u = value / scale``): it keeps the values
        that the views constrain little near the start. The relative loss is a
        relative squared error (1e-4 at 40 dB), so useful weights are small (1e-6 ..
        1e-4); the log loss is in natural-log units (1 dB of SNR is 0.23 of it), so its
        weights are larger; 0 (the default) fits the views alone. ``snr_db`` records
        the views' loss without it.
    validation : sequence of View
        Views the fit never optimises: every ``validate_every`` evaluations (iterations)
        and at the end, their SNR (dB, in the form of ``loss``: of their mean relative
        squared error, or their mean SNR with ``"log"``; each view at its own seed) is
        measured at the current iterate (L-BFGS: the best so far),
        and the fit returns the iterate they rate best (early stopping). Empty (the
        default): the fit's own last (Adam) or best (L-BFGS) iterate.
    validate_every : int
        The cadence, in evaluations (iterations), of the validation and of ``callback``.
    callback : callable or None
        ``callback(evaluations, model)`` at the same iterates as the validation: the
        number of evaluations done and the model at that iterate (the start's support
        with its values), e.g. to track the fit on views of one's own.
    progress : bool
        Show a tqdm progress bar with the current SNR.

    Returns
    -------
    FitResult
        The fitted model (the start's support with the new values) and the record.
    """
    _check_request(views, optimizer, loss, shared_paths, variant, iterations=iterations,
                   lr=lr, lr_end=lr_end, spp=spp, prior_weight=prior_weight,
                   validate_every=validate_every)
    from tqdm import tqdm  # lazy: only long jobs show a bar

    model = _start_model(start, ensemble)
    with tempfile.TemporaryDirectory(prefix="fit-images-") as tmp:
        start_path = save_sbrdf(Path(tmp) / "start.sbrdf", model, version=1)
        options = _plugin_options(decoder, ensemble, Path(tmp))
        scenes = _load_views(scene, views, material, start_path, spp, seed, variant,
                             options)
        monitor = Monitor(_load_views(scene, validation, material, start_path, spp, seed,
                                       variant, options),
                           None if callback is None else
                           (lambda n, vals: callback(n, replace(model, values=vals))),
                           validate_every, spp, loss == "log")
        settings = _settings(lr=lr, lr_end=lr_end, spp=spp, seed=seed, material=material,
                             decoder=decoder, variant=variant, shared_paths=shared_paths,
                             optimizer=optimizer, loss=loss, prior_weight=prior_weight,
                             validation=len(validation), validate_every=validate_every)
        fp = _fingerprint(scene, [*views, *validation], model, settings)
        opt, scales, u0 = _scaled_optimizer(model, lr)
        ckpt, done, snr = _resume(checkpoint_dir, opt, fp, monitor)
        current = functools.partial(_values, opt, scales)  # the model's values now
        if done == 0:
            monitor(0, current())  # the start
        t0, start_len = time.perf_counter(), len(snr)
        bar = tqdm(total=iterations, initial=min(done, iterations), disable=not progress,
                   desc="fit-images", unit="it")
        try:
            if optimizer == "lbfgs":
                _run_lbfgs(scene, scenes, opt, scales, done, iterations, snr, seed, spp, bar,
                           ckpt, checkpoint_every, fp, loss == "log", prior_weight, u0,
                           monitor)
            else:
                _run_adam(scene, scenes, opt, scales, u0, current, monitor, bar, snr,
                          range(done, iterations), iterations=iterations, lr=lr,
                          lr_end=lr_end, seed=seed, spp=spp, shared_paths=shared_paths,
                          log=loss == "log", prior_weight=prior_weight, ckpt=ckpt,
                          checkpoint_every=checkpoint_every, fp=fp)
        finally:
            bar.close()
        seconds = time.perf_counter() - t0
        values = current()
        if monitor.best is not None:  # early stopping: the validation views' best iterate
            values = monitor.best[2]
    ran = len(snr) - start_len  # L-BFGS may stop before its budget, converged
    fitted = replace(model, values=values, name=model.name)
    return FitResult(fitted, snr, seconds, seconds / max(ran, 1), max(len(snr), iterations
                     if optimizer == "adam" else 0), done, list(monitor.record),
                     monitor.best[1] if monitor.best is not None else None)


def load_views(items: Sequence[str], read, option: str = "--view") -> list[View]:
    """:class:`View` objects from ``IMAGE.exr[:KEY=VALUE,...]`` strings, reading each
    image with ``read`` (e.g. :func:`sparse_brdf.evaluation.render.read_exr`); errors
    name ``option`` (the command-line option that gave them)."""
    out = []
    for text in items:
        path, params = parse_view(text, option)
        out.append(View(np.asarray(read(path), np.float32), params, name=f"{option} {text}"))
    return out


def views_for(scene_params: Sequence[Mapping[str, object]],
              images: Sequence[np.ndarray],
              seeds: Sequence[int | None] | None = None) -> list[View]:
    """:class:`View` objects from parallel lists of scene defaults, images and (optional)
    the seeds the images were rendered with."""
    seeds = [None] * len(images) if seeds is None else list(seeds)
    return [View(np.asarray(img, np.float32), {k: str(v) for k, v in p.items()},
                 name=json.dumps(dict(p), sort_keys=True), seed=sd)
            for p, img, sd in zip(scene_params, images, seeds, strict=True)]

