"""Encoding to a byte budget: the largest encoding whose ``.sbrdf`` file fits N bytes.

Users pay in bytes, not in coefficients. :func:`encode_to_bytes` encodes a BRDF so that
its file holds at most ``n_bytes`` (header, name and checksum included), spending the
bytes where they gain most: every coefficient costs about the same bytes and, the
dictionaries being orthonormal, removes s^2 of squared error in the coded domain, so the
coefficients kept are the largest |s| over the three channels (:func:`fit_bytes`).

How (``docs/file-format.md``, "Byte budgets"): one encoding
(:func:`~sparse_brdf.coding.counted.encode_at`), whose dictionary search and first
least-squares fit use a coefficient count estimated from the budget (``first_count``).
Between the fill's fits, the file of the current fit is measured and the next round is
coded at the count that would fill the budget, aimed ``OVERSHOOT`` above it; after the
last fit, the largest |s| over the channels that fit are kept (a search on the exact
serialised size, :func:`fit_bytes`) and their values fitted again. So the
support, its values and the transform picked are chosen for the count that fits. Without
fill rounds to steer (``fill="missing"``, ``fill_iters=0``, a BRDF without invalid bins)
the encoder runs again instead: unless the first trim dropped at most ``MAX_TRIM`` of
the coefficients, at the count that fitted; an encoding that fits whole while the
encoder was capped is grown.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..brdf import BRDF
from ..errors import UsageError
from ..transforms import has_floor, has_lobe
from .coefficients import SparseBRDF
from .counted import choose_transform, encode_at
from .ensemble import Ensemble
from .fileformat import VERSION, as_stored, check_version, min_file_size, to_bytes
from .spec import N_BYTES, EncodeSpec

#: The byte budget of a file (at least its header, name and checksum: :func:`check_budget`).
PARAMETERS = {"n_bytes": N_BYTES}
#: First guess of the bytes per coefficient beyond the fixed part, per file version, as
#: ``(a, b)``: a - b ln(total coefficients). Version 2 compresses: with the step rule of
#: 2026-12-07, measured 1.9-2.0 bytes at 180 coefficients, 1.4-1.5 at 1,200 and 1.3-1.4
#: at 7,500 on six merl training materials (the default encoder); the guess is 0.95 of
#: that fit, a little on the low side, so
#: that the first count tends to overshoot the budget by a few per cent and is trimmed
#: rather than grown. The dictionary search runs at that count, so the closer the guess
#: the better the dictionaries suit the count that fits. Version 1: 8 bytes, exactly.
BYTES_GUESS = {1: (8.0, 0.0), 2: (2.22, 0.116)}
#: Without fill rounds to revise the count in: the largest share of an encoding's
#: coefficients a trim may drop and still be the result; a larger trim re-encodes at the
#: count that fitted, so that the encoder's own choices (transform, dictionaries) are made
#: for that count. 0 (the default): every trimmed encoding is encoded again. Measured on
#: the 14 merl test materials with the default fill (docs/benchmarks.md "Encode time"),
#: keeping the first encoding's trim (0.25) halved the time but lost 0.33 dB of mean
#: cosine-weighted SNR at 1,600 bytes and 0.21 dB at 6,300, up to 10.6 dB on one material
#: where the two counts choose different transforms.
MAX_TRIM = 0.0
#: How far above the budget the count of the fill's next round is aimed: the file of a
#: round's fit is measured, and the next round's values (hence their compressed size)
#: differ by a few per cent, so the count aims a little high and the last fit is trimmed
#: to the budget and fitted again (:func:`~sparse_brdf.coding.counted.encode_at`).
OVERSHOOT = 0.05
#: The share of the budget (beyond the file's fixed part) the last fit is trimmed below
#: the budget, so that its refit's new values still fit and the result is not trimmed
#: again after its errors were computed.
REFIT_SLACK = 0.005
#: Revise the count within the one encoding where the fill has rounds to do it in (the
#: default); False: encode again at the count that fitted, as without fill rounds (the
#: method before, kept so that benchmarks/bytes_passes.py can compare the two).
RECOUNT = True
#: Encoder runs at most (a first guess, a re-encoding after a large trim, or growth
#: while an encoding fits whole).
MAX_PASSES = 4


def truncate(model: SparseBRDF, keep: int) -> SparseBRDF:
    """``model`` with only its ``keep`` largest |s| over the three channels (ties: lower
    channel, then the model's order); each channel stays sorted by decreasing |s|."""
    mags = np.concatenate([np.abs(v) for v in model.values])
    chan = np.concatenate([np.full(v.size, c) for c, v in enumerate(model.values)])
    pos = np.concatenate([np.arange(v.size) for v in model.values])
    kept = np.lexsort((pos, chan, -mags))[:max(keep, 0)]
    locs, vals = [], []
    for c in range(3):
        idx = np.sort(pos[kept[chan[kept] == c]])
        locs.append(model.locations[c][idx])
        vals.append(model.values[c][idx])
    return dataclasses.replace(model, locations=locs, values=vals, stats=dict(model.stats))


def fit_bytes(model: SparseBRDF, n_bytes: int, version: int = VERSION) -> SparseBRDF:
    """The largest :func:`truncate` of ``model`` whose file of ``version`` holds at most
    ``n_bytes``, as the file holds it (:func:`~sparse_brdf.coding.fileformat.as_stored`, so
    ``to_bytes(result, version)`` is that file). ValueError if no coefficient fits.

    A search on the exact serialised size, which grows with the count kept (in small
    steps where version 2's quantisation step gets finer, ``fileformat.step_exponent``): a
    bracket from the count the bytes would hold in proportion, then bisection in it.
    """
    check_budget(model.name, n_bytes, version, (model.transform,))
    return _fit_bytes(model, n_bytes, version)


def _fit_bytes(model: SparseBRDF, n_bytes: int, version: int) -> SparseBRDF:
    """:func:`fit_bytes` on a checked budget."""
    total = int(model.n_coeffs.sum())

    def size(k: int) -> int:
        return len(to_bytes(truncate(model, k) if k < total else model, version))

    whole = size(total)
    if whole <= n_bytes:
        return as_stored(model, version)
    # bracket the count near the proportional estimate, then bisect within the bracket
    fixed = min_file_size(len(model.name.encode("utf-8")[:255]), version, model.transform)
    guess = min(max(total * (n_bytes - fixed) // max(whole - fixed, 1), 0), total - 1)
    step = max(total // 64, 1)
    lo, hi = guess, total
    if size(guess) <= n_bytes:
        while lo + step < hi and size(lo + step) <= n_bytes:
            lo, step = lo + step, 2 * step
        hi = min(lo + step, hi)
    else:
        hi = guess
        while hi > 0:
            lo = max(hi - step, 0)
            if lo == 0 or size(lo) <= n_bytes:
                break
            hi, step = lo, 2 * step
    keep = _largest(lo, hi, lambda k: size(k) <= n_bytes)
    return as_stored(truncate(model, keep), version)


def _largest(lo: int, hi: int, ok) -> int:
    """The largest k in [lo, hi) with ok(k), given ok(lo), not ok(hi) and ok falling
    once (binary search)."""
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


def check_budget(name: str, n_bytes: int, version: int = VERSION,
                 transforms: tuple[str, ...] = ()) -> None:
    """:class:`~sparse_brdf.errors.UsageError` (a ValueError) unless a file of ``version``
    named ``name`` can hold a coefficient in ``n_bytes`` under each of ``transforms``
    (none given: a transform without a gain; the message names ``--bytes``)."""
    check_version(version)
    _check_fixed(name, n_bytes, version, transforms)


def _check_fixed(name: str, n_bytes: int, version: int,
                 transforms: tuple[str, ...] = ()) -> int:
    """:func:`check_budget` for a checked version; returns the file's fixed part (its
    bytes before the first coefficient), the size checked against."""
    plain = min_file_size(len(name.encode("utf-8")[:255]), version)
    fixed = max([plain, *(min_file_size(len(name.encode("utf-8")[:255]), version, t)
                          for t in transforms)])
    if not isinstance(n_bytes, (int, np.integer)) or n_bytes <= fixed:
        lobe = any(has_lobe(t) for t in transforms)
        floor = any(has_floor(t) for t in transforms)
        what = "header, name and checksum" + (
            "" if fixed <= plain else ", and the lobe transform's gain, base lobe and floor"
            if floor else ", and the lobe transform's gain and base lobe"
            if lobe else ", and the level transform's gain")
        raise UsageError(f"--bytes {n_bytes}: a version-{version} .sbrdf file of {name!r} "
                         f"takes {fixed} bytes before its first coefficient ({what}); give "
                         f"more than {fixed}")
    return fixed


def encode_to_bytes(brdf: BRDF, ensemble: Ensemble | None = None, n_bytes: int | None = None,
                    version: int = VERSION, **encode_options) -> SparseBRDF:
    """Encode ``brdf`` so that its ``.sbrdf`` file holds at most ``n_bytes``.

    The largest encoding whose file fits, the coefficients kept the largest over the
    channels (see the module doc for the search).

    Parameters
    ----------
    brdf : BRDF
        The material, on the ensemble's grid.
    ensemble : Ensemble, optional
        Default: the shipped default ensemble.
    n_bytes : int
        The budget: the whole file in bytes, header and name included (required; more
        than a file of this name without coefficients takes).
    version : int
        The ``.sbrdf`` version whose bytes are counted: 2 (default) or 1.
    **encode_options
        Any keyword of :func:`~sparse_brdf.coding.encode.encode` but ``n_coeffs``
        (``max_error``, ``transform``, ``selector``, ``fill``, ``fill_iters``, ``basis``,
        ``budget``).

    Returns
    -------
    SparseBRDF
        The model as the file holds it (values quantised for version 2), so that
        ``save_sbrdf(path, result, version)`` writes at most ``n_bytes``. ``stats`` are
        the encoder's, with the chosen transform's errors recomputed for the kept
        coefficients, and ``stats["byte_budget"]``: the budget, the file's size, the
        counts encoded and kept, and the passes.

    Raises
    ------
    UsageError
        Without ``n_bytes``, with ``n_coeffs``, for an unknown version, or for a budget
        too small to hold a coefficient.

    See Also
    --------
    encode_to_bytes_with : the same on a resolved :class:`~sparse_brdf.coding.spec.EncodeSpec`.
    """
    if "n_coeffs" in encode_options or n_bytes is None:
        raise UsageError("encode_to_bytes: give a byte budget n_bytes (and no n_coeffs)")
    spec = EncodeSpec.build(ensemble, n_bytes=n_bytes, version=version, **encode_options)
    return encode_to_bytes_with(brdf, spec)


def encode_to_bytes_with(brdf: BRDF, spec: EncodeSpec) -> SparseBRDF:
    """:func:`encode_to_bytes` on a resolved request (``spec.n_bytes`` set; trusted, as
    :meth:`~sparse_brdf.coding.spec.EncodeSpec.build` checked it): only whether this
    material's file holds a coefficient in the budget is checked (its name's bytes count).
    """
    n_bytes, version, ens = spec.n_bytes, spec.version, spec.ensemble
    fixed = _check_fixed(brdf.name, n_bytes, version, tuple(spec.transforms))
    atoms = int(np.prod(ens.shape))
    n = _clip(math.ceil(first_count(n_bytes - fixed, version) / 3), atoms)
    joint = spec.joint
    size = _ByteSize(n_bytes, version, fixed, atoms, joint) if RECOUNT else None
    model = encode_at(brdf, dataclasses.replace(spec, n_coeffs=n), size)
    if "recount" in model.stats["transforms"][model.transform]:  # one encoding did it
        return _finish(brdf, ens, model, _fit_bytes(model, n_bytes, version), n_bytes,
                       version, 1)
    # no fill rounds to recount in: encode again at the count that fitted (or larger)
    passes: dict[int, tuple[SparseBRDF, SparseBRDF]] = {}  # count -> (encoded, fitted)
    passes[n] = (model, _fit_bytes(model, n_bytes, version))
    n, trimmed = _next_count(*passes[n], n, n_bytes, fixed, version, atoms, False, joint)
    while len(passes) < MAX_PASSES and n not in passes:
        model = encode_at(brdf, dataclasses.replace(spec, n_coeffs=n))
        passes[n] = (model, _fit_bytes(model, n_bytes, version))
        n, trimmed = _next_count(*passes[n], n, n_bytes, fixed, version, atoms, trimmed,
                                 joint)
    # the pass at the count the search settled on (else the last)
    model, fit = passes.get(n, list(passes.values())[-1])
    return _finish(brdf, ens, model, fit, n_bytes, version, len(passes))


@dataclasses.dataclass(frozen=True)
class _ByteSize:
    """Steers one encoding to a byte budget (:class:`~sparse_brdf.coding.fill.SizeControl`):
    between the fill's fits, the count whose file would fill the budget, estimated from
    the current fit's file (bytes in proportion to coefficients) and aimed ``OVERSHOOT``
    above it; after the last fit, the largest coefficients that fit (:func:`fit_bytes`)."""

    n_bytes: int
    version: int
    fixed: int
    atoms: int
    joint: bool

    def recount(self, model: SparseBRDF) -> int:
        counts = model.n_coeffs
        size = len(to_bytes(model, self.version))
        scale = (1 + OVERSHOOT) * (self.n_bytes - self.fixed) / max(size - self.fixed, 1)
        total = int(counts.sum()) if self.joint else int(counts.max())
        return _clip(math.ceil(scale * total / (3 if self.joint else 1)), self.atoms)

    def trim(self, model: SparseBRDF) -> SparseBRDF:
        # REFIT_SLACK below the budget: the refit that follows moves the values, and with
        # them the compressed size, by a few bytes (version 1's size is the count's alone)
        slack = (0 if self.version == 1
                 else max(4, math.ceil(REFIT_SLACK * (self.n_bytes - self.fixed))))
        total = int(model.n_coeffs.sum())
        keep = int(_fit_bytes(model, max(self.n_bytes - slack, self.fixed + 1),
                              self.version).n_coeffs.sum())
        return truncate(model, keep) if keep < total else model


def first_count(payload: int, version: int = VERSION) -> int:
    """The first guess (``BYTES_GUESS``) of the coefficients, over the three channels,
    that ``payload`` bytes beyond a file's fixed part hold."""
    a, b = BYTES_GUESS[version]
    total = max(payload / a, 1.0)
    for _ in range(8):  # fixed point of total = payload / (a - b ln total)
        total = payload / max(a - b * math.log(max(total, 1.0)), 0.5)
    return max(int(total), 1)


def _clip(n: int, atoms: int) -> int:
    return int(min(max(n, 1), atoms))


def _next_count(model: SparseBRDF, fit: SparseBRDF, n: int, n_bytes: int, fixed: int,
                version: int, atoms: int, trimmed: bool, joint: bool) -> tuple[int, bool]:
    """The encoder's next count and whether a pass was trimmed: ``n`` (done) once an
    encoding was trimmed by at most ``MAX_TRIM`` (or a second time), the count that
    fitted after a larger trim; if one fitted whole while the encoder used its whole
    budget, a larger count; else ``n`` (done: the encoder stopped by itself)."""
    kept, total = fit.n_coeffs, int(model.n_coeffs.sum())
    if int(kept.sum()) < total:  # trimmed: done, or encode once at the count that fitted
        if trimmed or kept.sum() >= (1 - MAX_TRIM) * total:
            return n, True
        return _clip(math.ceil(kept.sum() / 3) if joint else int(kept.max()), atoms), True
    capped = total >= 3 * n if joint else int(model.n_coeffs.max()) >= n
    if trimmed or not capped or total == 0:  # done, or the encoder stopped by itself
        return n, trimmed
    size = len(to_bytes(model, version))
    per = max((size - fixed) / total, 0.5)
    return _clip(math.ceil(1.2 * (n_bytes - fixed) / per / 3), atoms), False


def _finish(brdf: BRDF, ens: Ensemble, model: SparseBRDF, fit: SparseBRDF, n_bytes: int,
            version: int, passes: int) -> SparseBRDF:
    """``fit`` as its file holds it, checked against the budget, with its statistics."""
    out = fit
    while len(to_bytes(out, version)) > n_bytes:  # not expected: the search measured it
        out = as_stored(truncate(out, int(out.n_coeffs.sum()) - 1), version)
    stats = dict(model.stats)
    if int(out.n_coeffs.sum()) < int(model.n_coeffs.sum()):  # errors of what is kept
        errors = choose_transform(brdf, {out.transform: dataclasses.replace(out, stats={})},
                                  ens, stats.get("selector", "gamma-mse"),
                                  ).stats["transforms"][out.transform]
        stats["transforms"] = {**stats.get("transforms", {}),
                               out.transform: {**stats.get("transforms", {}).get(
                                   out.transform, {}), **errors}}
    stats["byte_budget"] = {"budget": int(n_bytes), "file": len(to_bytes(out, version)),
                      "version": version, "encoded": model.n_coeffs.tolist(),
                      "kept": out.n_coeffs.tolist(), "passes": passes}
    out.stats = stats
    return out


__all__ = ["BYTES_GUESS", "check_budget", "encode_to_bytes", "encode_to_bytes_with",
           "first_count", "fit_bytes", "truncate"]
