"""Error metrics (``docs/method.md``, "Error metrics"). One implementation each, shared by
every caller."""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from .coords import MERL_SHAPE, bin_solid_angle_hd, cos_io, cosine_product, dirs_to_bins
from .errors import ImageFileError

GAMMA = 2.0


#: Labels of the two rendering-SNR forms, as printed and recorded everywhere.
WHOLE_IMAGE = "whole-image"
OBJECT_ONLY = "object-only"


#: Label of the perceptual form, as printed and recorded everywhere.
FLIP = "HDR-FLIP"

#: Pixels per degree of visual angle HDR-FLIP assumes: its default viewing condition
#: (a 0.7 m wide 4K monitor seen from 0.7 m), the one its published figures use.
FLIP_PPD = 67.0


class SNRForms(NamedTuple):
    """Rendering SNR in both forms, as returned by :func:`snr_forms`.

    Attributes
    ----------
    whole : float
        SNR in dB over every pixel, background included (the paper's form).
    object : float
        SNR in dB over the pixels whose camera rays hit the object (the strict form).
    """

    whole: float
    object: float

    def as_dict(self) -> dict[str, float]:
        """The two forms under the keys the bench records.

        Returns
        -------
        dict of str to float
            ``{"snr_whole": whole, "snr_object": object}``, in dB.
        """
        return {"snr_whole": self.whole, "snr_object": self.object}

    def __str__(self) -> str:
        return f"{WHOLE_IMAGE} {self.whole:.2f} dB, {OBJECT_ONLY} {self.object:.2f} dB"


def render_snr(ref: np.ndarray, img: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Rendering SNR in dB: 10 log10(sum ref^2 / sum (ref - img)^2).

    Parameters
    ----------
    ref, img : numpy.ndarray
        Linear images of equal shape (H, W, C), the reference and the rendering to score.
    mask : numpy.ndarray, optional
        Bool (H, W): the pixels summed over (the object-only form). None: every pixel
        (the whole-image form).

    Returns
    -------
    float
        The SNR in dB; ``inf`` for identical images, ``-inf`` for a zero reference with a
        nonzero image.

    Raises
    ------
    ImageFileError
        (a ValueError) On a shape mismatch, NaN or inf pixels, or a mask that selects no
        pixel.
    """
    ref = np.asarray(ref, dtype=np.float64)
    img = np.asarray(img, dtype=np.float64)
    if ref.shape != img.shape:
        raise ImageFileError(f"image shapes differ: reference {ref.shape}, image {img.shape}")
    for what, a in (("reference", ref), ("image", img)):
        if not np.all(np.isfinite(a)):
            raise ImageFileError(f"{what} image holds {int((~np.isfinite(a)).sum())} NaN/inf "
                                 "values")
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != ref.shape[:mask.ndim]:
            raise ImageFileError(f"mask shape {mask.shape} does not match the images {ref.shape}")
        if not mask.any():
            raise ImageFileError("the object mask selects no pixel")
        ref, img = ref[mask], img[mask]
    signal = float(np.sum(ref**2))
    noise = float(np.sum((ref - img) ** 2))
    if noise == 0.0:
        return float("inf")
    if signal == 0.0:
        return float("-inf")
    return 10.0 * np.log10(signal / noise)


def snr_forms(ref: np.ndarray, img: np.ndarray, mask: np.ndarray) -> SNRForms:
    """Both rendering-SNR forms of ``img`` against ``ref``.

    Parameters
    ----------
    ref, img : numpy.ndarray
        Linear images of equal shape (H, W, C).
    mask : numpy.ndarray
        Bool (H, W): the object pixels, e.g. from
        :func:`sparse_brdf.evaluation.render.object_mask`.

    Returns
    -------
    SNRForms
        ``whole`` (every pixel) and ``object`` (the masked pixels), in dB.

    Raises
    ------
    ValueError
        As :func:`render_snr`.
    """
    return SNRForms(render_snr(ref, img), render_snr(ref, img, mask))


class FlipResult(NamedTuple):
    """HDR-FLIP of an image against a reference, as returned by :func:`hdr_flip`.

    Attributes
    ----------
    mean : float
        The mean of the error map over the scored pixels, in [0, 1]; 0 for identical images.
    map : numpy.ndarray
        float32 (H, W): the per-pixel error over the whole image, in [0, 1].
    """

    mean: float
    map: np.ndarray


def hdr_flip(ref: np.ndarray, img: np.ndarray, mask: np.ndarray | None = None,
             ppd: float = FLIP_PPD) -> FlipResult:
    """HDR-FLIP (Andersson et al. 2020, 2021), the perceptual difference of two HDR
    images, computed by NVIDIA's ``flip-evaluator``.

    The error map is computed on the whole image (FLIP filters over a neighbourhood) and
    averaged over the pixels of ``mask``. The tone mapper is ACES. HDR-FLIP takes the
    largest error over a range of exposures, from the one that maps the reference's
    brightest pixel to 0.85 to the one that maps its median luminance to 0.85; with a mask,
    that median is the object's (:func:`flip_exposures`), since a black background that
    fills half the image would otherwise push the longest exposure to 2^24 and score
    colour differences a millionth of the object's brightness.

    Parameters
    ----------
    ref, img : numpy.ndarray
        Linear images of equal shape (H, W, 3) or (H, W, 1) (mono, repeated to grey RGB),
        in linear sRGB / Rec. 709 primaries, non-negative.
    mask : numpy.ndarray, optional
        Bool (H, W): the pixels averaged over (the object's). None: every pixel.
    ppd : float
        Pixels per degree of visual angle; FLIP's default of 67.

    Returns
    -------
    FlipResult
        The mean over the mask, and the whole error map.

    Raises
    ------
    ImageFileError
        (a ValueError) On a shape mismatch, NaN, inf or negative pixels, a black reference
        (it has no exposure range), or a mask that selects no pixel.
    """
    import flip_evaluator  # its import loads a compiled module: only where FLIP is asked for

    pair = []
    for what, a in (("reference", ref), ("image", img)):
        a = np.asarray(a, dtype=np.float32)
        if a.ndim == 2:
            a = a[..., None]
        if a.ndim != 3 or a.shape[2] not in (1, 3):
            raise ImageFileError(f"HDR-FLIP needs (H, W, 3) or (H, W, 1) images; the {what} "
                                 f"is {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ImageFileError(f"{what} image holds {int((~np.isfinite(a)).sum())} NaN/inf "
                                 "values")
        if np.any(a < 0):
            raise ImageFileError(f"{what} image holds negative values: HDR-FLIP scores "
                                 "non-negative radiance")
        pair.append(np.ascontiguousarray(np.repeat(a, 3, axis=2) if a.shape[2] == 1 else a))
    ref, img = pair
    if ref.shape != img.shape:
        raise ImageFileError(f"image shapes differ: reference {ref.shape}, image {img.shape}")
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != ref.shape[:2]:
            raise ImageFileError(f"mask shape {mask.shape} does not match the images {ref.shape}")
        if not mask.any():
            raise ImageFileError("the object mask selects no pixel")
    if not np.any(ref > 0):  # FLIP would end the process: its exposure range is undefined
        raise ImageFileError("the reference image is black: HDR-FLIP has no exposure range")
    params = {"ppd": float(ppd)}
    if mask is not None:
        params.update(flip_exposures(ref, mask))
    err, _, _ = flip_evaluator.evaluate(ref, img, "HDR", inputsRGB=True, applyMagma=False,
                                        computeMeanError=False, parameters=params)
    err = np.asarray(err, dtype=np.float32).reshape(ref.shape[:2])
    scored = err if mask is None else err[mask]
    return FlipResult(float(np.mean(scored, dtype=np.float64)), err)


#: The ACES fit FLIP assumes (Narkowicz 2016, with FLIP's pre-exposure of 0.6 folded in):
#: tone(x) = (K[0] x^2 + K[1] x + K[2]) / (K[3] x^2 + K[4] x + K[5]).
_ACES = (0.6 * 0.6 * 2.51, 0.6 * 0.03, 0.0, 0.6 * 0.6 * 2.43, 0.6 * 0.59, 0.14)
#: The tone-mapped value that bounds HDR-FLIP's exposure range at both ends.
_FLIP_T = 0.85
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722], np.float64)


def flip_exposures(ref: np.ndarray, mask: np.ndarray) -> dict[str, float | int]:
    """HDR-FLIP's exposure range (Andersson et al. 2021), measured on the object's pixels.

    The start exposure maps the brightest luminance to a tone-mapped 0.85, the stop
    exposure the median luminance of the pixels in ``mask`` (the median of their nonzero
    ones, if most are black); one exposure per stop between them, at least two.

    Parameters
    ----------
    ref : numpy.ndarray
        float32 (H, W, 3) linear RGB, the reference.
    mask : numpy.ndarray
        Bool (H, W), selecting at least one pixel.

    Returns
    -------
    dict
        ``startExposure``, ``stopExposure`` (log2 of the exposure factor) and
        ``numExposures``, as ``flip_evaluator.evaluate`` takes them.
    """
    k0, k1, k2, k3, k4, k5 = _ACES
    a, b = k1 - k4 * _FLIP_T, k2 - k5 * _FLIP_T  # the root of tone(x) = t
    c0, c1 = a / (k0 - k3 * _FLIP_T), b / (k0 - k3 * _FLIP_T)
    x_t = -0.5 * c0 + np.sqrt((0.5 * c0) ** 2 - c1)
    lum = np.asarray(ref, np.float64) @ _LUMINANCE
    obj = lum[mask]
    y_lo = float(np.median(obj))
    if y_lo <= 0.0:
        y_lo = float(np.median(obj[obj > 0])) if np.any(obj > 0) else float(lum.max())
    start = float(np.log2(x_t / lum.max()))
    stop = max(float(np.log2(x_t / y_lo)), start)
    return {"startExposure": start, "stopExposure": stop,
            "numExposures": max(2, int(np.ceil(stop - start)))}


def rae(ref: np.ndarray, rec: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Relative absolute error sum |ref - rec| / sum |ref| over valid bins.

    Parameters
    ----------
    ref, rec : numpy.ndarray
        Linear BRDF values of equal shape, e.g. (n_h, n_d, n_p, 3): the reference and the
        reconstruction.
    valid : numpy.ndarray, optional
        Bool mask over the leading grid axes, e.g. (n_h, n_d, n_p), broadcast over the
        channels; None: every bin.

    Returns
    -------
    float
        The error (dimensionless; 0 is exact). With an all-zero reference: 0.0 if ``rec``
        is zero too, else 1.0.

    Raises
    ------
    ValueError
        If the shapes differ.
    """
    ref, rec = _masked(ref, rec, valid)
    den = float(np.sum(np.abs(ref), dtype=np.float64))
    num = float(np.sum(np.abs(ref - rec), dtype=np.float64))
    return num / den if den > 0 else float(np.sum(np.abs(rec)) > 0)


def gamma_mse(ref: np.ndarray, rec: np.ndarray, valid: np.ndarray | None = None,
              gamma: float = GAMMA) -> float:
    """Mean squared error of x ** (1 / gamma) over valid bins (the paper's selector).

    Parameters
    ----------
    ref, rec : numpy.ndarray
        Linear BRDF values of equal shape, e.g. (n_h, n_d, n_p, 3); negative values count
        as 0.
    valid : numpy.ndarray, optional
        Bool mask over the leading grid axes (broadcast over the channels); None: every
        bin.
    gamma : float
        The mapping's exponent is 1 / ``gamma`` (default 2: square roots).

    Returns
    -------
    float
        The mean over the selected entries, or NaN if none is selected.

    Raises
    ------
    ValueError
        If the shapes differ.
    """
    ref, rec = _masked(ref, rec, valid)
    if ref.size == 0:
        return float("nan")
    if gamma == 2.0:  # x ** 0.5, several times faster as a square root
        d = np.sqrt(np.maximum(ref, 0)) - np.sqrt(np.maximum(rec, 0))
    else:
        g = 1.0 / gamma
        d = np.maximum(ref, 0) ** g - np.maximum(rec, 0) ** g
    return float(np.sum(d * d, dtype=np.float64)) / ref.size


def mse(ref: np.ndarray, rec: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Plain mean squared error of linear BRDF values over valid bins.

    Parameters
    ----------
    ref, rec : numpy.ndarray
        Linear BRDF values of equal shape.
    valid : numpy.ndarray, optional
        Bool mask over the leading grid axes; None: every bin.

    Returns
    -------
    float
        The mean over the selected entries, or NaN if none is selected.
    """
    ref, rec = _masked(ref, rec, valid)
    if ref.size == 0:
        return float("nan")
    d = ref - rec
    return float(np.sum(d * d, dtype=np.float64)) / ref.size


def cosine_weighted_snr(ref: np.ndarray, rec: np.ndarray, valid: np.ndarray) -> float:
    """BRDF-space SNR of rho * cos_i * cos_o over valid bins.

    Parameters
    ----------
    ref, rec : numpy.ndarray
        Linear BRDF values (n_h, n_d, n_p, 3) on the MERL-style grid: the reference and
        the reconstruction.
    valid : numpy.ndarray
        Bool (n_h, n_d, n_p): the bins counted.

    Returns
    -------
    float
        10 log10(sum (rho_ref c)^2 / sum ((rho_ref - rho_rec) c)^2) in dB, with
        c = max(cos_i cos_o, 0) at each bin; ``inf`` if exact.

    Raises
    ------
    ValueError
        If the shapes differ.
    """
    c = np.clip(cosine_product(ref.shape[:3]), 0, None)[..., None]
    ref, rec = _masked(ref * c, rec * c, valid)
    return render_snr(ref, rec)


@functools.lru_cache(maxsize=4)
def make_render_proxy(shape: tuple[int, int, int] = MERL_SHAPE,
                      blur_deg: float = 2.0) -> dict[str, np.ndarray]:
    """The kernel of :func:`render_proxy_error` on a grid (cached per shape; read-only).

    Per bin: its measure in (wi, wo) space ``omega`` (:func:`coords.bin_solid_angle`) and
    the point-light, cos_o-pixel weight cos_i cos_o (cos_i + cos_o) / 2 omega (cosines at
    bin centres, clamped >= 0; symmetrised by reciprocity), summed over cells of about
    ``blur_deg`` degrees of theta_h (``starts``: first theta_h bin of each cell).
    Arrays are (cells or n1, n2, n3) without a channel axis.
    """
    n1, n2, n3 = shape
    th = ((np.arange(n1) + 0.5) / n1) ** 2 * np.pi / 2  # bin centres (square-root spacing)
    td = (np.arange(n2) + 0.5) / n2 * np.pi / 2
    pd = (np.arange(n3) + 0.5) / n3 * np.pi
    ci, co = cos_io(th[:, None, None], td[None, :, None], pd[None, None, :])
    np.maximum(ci, 0.0, out=ci)
    np.maximum(co, 0.0, out=co)
    # the bins' measure does not depend on phi_d: work on its (n1, n2) plane and expand
    # at the end (the same values, in the same order of operations, as on the full grid)
    hd = bin_solid_angle_hd(shape)
    point = ci
    sum_io = ci + co
    point *= co
    point *= 0.5
    point *= sum_io
    point *= hd[:, :, None]  # cos_i cos_o (cos_i + cos_o) / 2 omega
    cell = np.floor(np.degrees(th) / blur_deg)
    starts = np.flatnonzero(np.r_[True, cell[1:] != cell[:-1]])
    out = {"omega": np.repeat(hd.astype(np.float32)[:, :, None], n3, axis=2),
           "starts": starts,
           "cell_omega": np.repeat(np.add.reduceat(hd, starts, axis=0)[:, :, None], n3,
                                   axis=2),
           "cell_point": np.add.reduceat(point, starts, axis=0)}
    return _read_only(out)


def _read_only(kernel: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``kernel`` with every array made read-only (a cached kernel is shared)."""
    for a in kernel.values():
        a.flags.writeable = False
    return kernel


def _two_tables(ref, rec) -> tuple[np.ndarray, np.ndarray, bool, tuple[int, int, int]]:
    """A proxy's two tables as arrays, whether they are channel-first (told apart by the
    last axis: phi_d, not at most 4 colour channels) and their grid; a ValueError unless
    they are two equal 4-D arrays."""
    ref = np.asarray(ref)
    rec = np.asarray(rec)
    if ref.shape != rec.shape or ref.ndim != 4:
        raise ValueError(f"expected two equal 4-D arrays, got {ref.shape} and {rec.shape}")
    first = ref.shape[-1] > 4
    return ref, rec, first, tuple(ref.shape[1:] if first else ref.shape[:3])


def render_proxy_error(ref: np.ndarray, rec: np.ndarray,
                       kernel: dict[str, np.ndarray] | None = None,
                       valid: np.ndarray | None = None) -> float:
    """A BRDF-space predictor of a rendering's squared error (``docs/method.md``,
    "Encoding"): the linear error averaged (with the bins' solid angles) over cells of
    ~2 degrees of theta_h, squared, and weighted by the cell's sum of
    cos_i cos_o (cos_i + cos_o) / 2 times the bins' solid angle in (wi, wo) space.

    ``ref``/``rec``: linear BRDF values, channel-last (n1, n2, n3, C) or channel-first
    (C, n1, n2, n3) (told apart by the last axis: at most 4 colour channels), 0 on
    invalid bins, or give ``valid`` (bool (n1, n2, n3)) to zero them here. ``kernel``:
    :func:`make_render_proxy` of the grid (default: the cached one, 2-degree cells).
    Smaller is better; the sum is accumulated in float64.
    """
    ref, rec, first, shape = _two_tables(ref, rec)
    k = make_render_proxy(shape) if kernel is None else kernel
    if k["omega"].shape != tuple(shape):
        raise ValueError(f"kernel grid {k['omega'].shape} does not match the arrays' {shape}")
    d = np.asarray(ref, np.float32) - np.asarray(rec, np.float32)
    if valid is not None:
        d = np.where(valid, d, np.float32(0)) if first else np.where(valid[..., None], d, 0)
    if first:
        d = np.add.reduceat(d * k["omega"], k["starts"], axis=1) / k["cell_omega"]
        w = k["cell_point"]
    else:
        d = np.add.reduceat(d * k["omega"][..., None], k["starts"], axis=0)
        d /= k["cell_omega"][..., None]
        w = k["cell_point"][..., None]
    return float(np.sum(d * d * w, dtype=np.float64))


#: The albedo proxy's sampling: outgoing polar angles, and incident directions per
#: outgoing one (polar x azimuth), all at cell midpoints.
ALBEDO_SAMPLES = (24, 40, 80)


@functools.lru_cache(maxsize=4)
def make_albedo_proxy(shape: tuple[int, int, int] = MERL_SHAPE) -> dict[str, np.ndarray]:
    """The kernel of :func:`albedo_proxy_error` on a grid (cached per shape; read-only).

    For each of ``ALBEDO_SAMPLES[0]`` outgoing polar angles theta_o (midpoints of equal
    steps over [0, pi/2], azimuth 0), a midpoint rule over the incident hemisphere
    (``ALBEDO_SAMPLES[1]`` polar by ``ALBEDO_SAMPLES[2]`` azimuth cells): ``grid`` (3,),
    the grid's shape; ``index`` (n_o, n_w), the flat grid bin of each (w_i, w_o) pair;
    ``weight`` (n_w,), cos_i times the cell's solid angle (sr); ``outgoing`` (n_o,), cos_o
    times theta_o's solid angle 2 pi sin(theta_o) d theta_o (sr), the share of a
    uniformly lit sphere's pixels that see that theta_o.
    """
    n_o, n_t, n_p = ALBEDO_SAMPLES
    step_o, step_t, step_p = np.pi / 2 / n_o, np.pi / 2 / n_t, 2 * np.pi / n_p
    to = (np.arange(n_o) + 0.5) * step_o
    ti = (np.arange(n_t) + 0.5) * step_t
    pi = (np.arange(n_p) + 0.5) * step_p
    st, ct = np.sin(ti)[:, None], np.cos(ti)[:, None]
    wi = np.stack(np.broadcast_arrays(st * np.cos(pi), st * np.sin(pi), ct), -1).reshape(-1, 3)
    weight = np.broadcast_to(ct * st * step_t * step_p, (n_t, n_p)).reshape(-1)
    wo = np.stack([np.sin(to), np.zeros(n_o), np.cos(to)], -1)
    bins = dirs_to_bins(wi[None, :, :], wo[:, None, :], tuple(shape))
    return _read_only({"grid": np.array(shape, np.int64),
                       "index": np.ravel_multi_index(bins, tuple(shape)),
                       "weight": weight.astype(np.float64),
                       "outgoing": np.cos(to) * 2 * np.pi * np.sin(to) * step_o})


def albedo_proxy_error(ref: np.ndarray, rec: np.ndarray,
                       kernel: dict[str, np.ndarray] | None = None,
                       valid: np.ndarray | None = None) -> float:
    """A BRDF-space predictor of a rendering's squared error under uniform light
    (``docs/method.md``, "Encoding"): per outgoing direction the error of the directional
    albedo, the integral over w_i of (ref - rec) cos_i, squared, summed over theta_o with
    cos_o times its solid angle. Errors of one sign over many bins add up here, as a
    pixel under broad light adds them; :func:`render_proxy_error` sees each bin alone.

    ``ref``/``rec``: linear BRDF values, channel-last (n1, n2, n3, C) or channel-first
    (C, n1, n2, n3) (told apart as :func:`render_proxy_error` does), 0 on invalid bins, or
    give ``valid`` (bool (n1, n2, n3)) to zero them here. ``kernel``:
    :func:`make_albedo_proxy` of the grid (default: the cached one). Smaller is better;
    float64 sums.
    """
    ref, rec, first, shape = _two_tables(ref, rec)
    k = make_albedo_proxy(shape) if kernel is None else kernel
    if tuple(k["grid"]) != shape:
        raise ValueError(f"kernel grid {tuple(k['grid'])} does not match the arrays' {shape}")
    idx = k["index"]

    def at_samples(x: np.ndarray) -> np.ndarray:  # (C, n_o, n_w), only the sampled bins
        x = x.reshape(x.shape[0], -1) if first else x.reshape(-1, x.shape[-1]).T
        return np.asarray(x[:, idx], np.float64)

    d = at_samples(ref) - at_samples(rec)
    if valid is not None:
        d *= np.asarray(valid, bool).reshape(-1)[idx]
    albedo = d @ k["weight"]  # (C, n_o)
    return float(np.sum(albedo * albedo * k["outgoing"], dtype=np.float64))


def _masked(ref: np.ndarray, rec: np.ndarray, valid: np.ndarray | None):
    """Flat arrays of the valid entries, float32 or float64 (float32 inputs stay float32;
    the metrics accumulate their sums in float64)."""
    ref = np.asarray(ref)
    rec = np.asarray(rec)
    if ref.shape != rec.shape:
        raise ValueError(f"shapes differ: reference {ref.shape}, reconstruction {rec.shape}")
    if valid is not None:
        valid = np.asarray(valid, dtype=bool)
        if ref.ndim != valid.ndim + 1:
            valid = np.broadcast_to(valid, ref.shape)
        ref, rec = ref[valid], rec[valid]
    dtype = np.result_type(ref.dtype, rec.dtype, np.float32)
    return (np.asarray(ref, dtype).ravel(), np.asarray(rec, dtype).ravel())
