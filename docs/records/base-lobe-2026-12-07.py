"""The lobe study's prototype (docs/records/base-lobe-2026-12-07.md), an outside model of
``sparse-brdf bench``: save it as ``basemodel.py`` beside the config and name it
``basemodel:BaseSparse:OPTIONS`` in ``models``. Not part of the package.

Per material: a lobe b_c = kd_c + ks_c D(theta_h; alpha) (GGX; ``denom=1`` divides D by
4 max(cos_i cos_o, 0.01)), fitted by relative least squares; the default encoder then codes
the opponent mix of t_c = w ln((rho_c c + f) / (b_c c + f)), w = ((b_c c + f) / L)^gamma,
f = eps L, c = 1 or clip(cos_i cos_o, 0.01, 1) (``cos``), L the material's level; ``sel``
("render" or "gmse") encodes both forms and keeps the one the selector prefers. The study's
other options: ``ff``/``fp`` (fit weights (mean rho + ff L)^-fp), ``logfit`` (fit in the
log domain), ``fix`` (one scale per channel fitted after decoding), ``lobes=2``.
"""
import contextlib

import numpy as np
from scipy.optimize import nnls

from sparse_brdf.coding import encode as enc_mod
from sparse_brdf.coding import fill as fill_mod
from sparse_brdf.coding.encode import encode
from sparse_brdf.coding.ensemble import resolve_ensemble
from sparse_brdf.coding.fileformat import as_stored, to_bytes
from sparse_brdf.compared.compact import Compact
from sparse_brdf.coords import bin_solid_angle, cosine_product, grid_angles
from sparse_brdf.metrics import gamma_mse, render_proxy_error
from sparse_brdf.transforms import cosine_weight, material_level, to_basis

ALPHAS = np.geomspace(0.003, 0.6, 30)


def ggx(shape, alpha, denom=0):
    """D(theta_h; alpha) at the bins' angles, optionally over the microfacet denominator."""
    c2 = np.cos(grid_angles(shape)[0]) ** 2
    a2 = alpha * alpha
    d = a2 / (np.pi * (c2 * (a2 - 1) + 1) ** 2)
    if denom:
        d = d / (4 * np.maximum(cosine_product(shape), 1e-2))
    return d


def fit_lobe(rho, valid, level, denom=0, ff=1.0, fp=1.0, alphas=ALPHAS):
    """alpha, and (3, 2) kd, ks per channel: nonnegative least squares with weights
    (mean_c rho + ff L)^-fp, alpha the best on the grid."""
    r = rho[:, valid].astype(np.float64)
    w = (r.mean(0) + ff * level) ** -fp
    best = None
    for alpha in alphas:
        a = np.stack([np.ones(r.shape[1]), ggx(rho.shape[1:], alpha, denom)[valid]], 1)
        fits = [nnls(a * w[:, None], r[c] * w) for c in range(3)]
        err = sum(res ** 2 for _, res in fits)
        if best is None or err < best[0]:
            best = (err, alpha, np.array([x for x, _ in fits]))
    return best[1], best[2]


def fit_lobe_log(rho, valid, level, eps, denom=0, seed=0):
    """The same lobe, Gauss-Newton on the squared log ratio, on 60,000 valid bins."""
    rng = np.random.default_rng(seed)
    idx = np.flatnonzero(valid.ravel())
    idx = np.sort(rng.choice(idx, min(idx.size, 60000), replace=False))
    r = rho.reshape(3, -1)[:, idx].astype(np.float64)
    f = eps * level
    best = None
    for alpha in ALPHAS:
        a = np.stack([np.ones(idx.size), ggx(rho.shape[1:], alpha, denom).ravel()[idx]], 1)
        w0 = 1.0 / (r.mean(0) + level)
        err, coef = 0.0, []
        for c in range(3):
            x, _ = nnls(a * w0[:, None], r[c] * w0)
            for _ in range(8):
                b = a @ x + f
                step = np.linalg.lstsq(a / b[:, None], np.log(r[c] + f) - np.log(b), rcond=None)[0]
                x = np.maximum(x + step, 0.0)
            res = np.log(r[c] + f) - np.log(a @ x + f)
            err += float(res @ res)
            coef.append(x)
        if best is None or err < best[0]:
            best = (err, alpha, np.array(coef))
    return best[1], best[2]


def fit_two_lobes(rho, valid, level, ff=1.0, fp=1.0, seed=0):
    """Two GGX lobes over a constant, alpha pairs on a 24-value grid, on a subsample that
    keeps every valid bin below 3 degrees of theta_h."""
    th = grid_angles(rho.shape[1:])[0].ravel()
    v = valid.ravel()
    peak = np.flatnonzero(v & (th < np.radians(3)))
    rest = np.flatnonzero(v & (th >= np.radians(3)))
    n = min(rest.size, 80000)
    idx = np.sort(np.concatenate([peak, np.random.default_rng(seed).choice(rest, n, replace=False)]))
    wsamp = np.where(np.isin(idx, rest), rest.size / n, 1.0)
    r = rho.reshape(3, -1)[:, idx].astype(np.float64)
    w = np.sqrt(wsamp) * (r.mean(0) + ff * level) ** -fp
    alphas = np.geomspace(0.0003, 0.6, 24)
    gs = [ggx(rho.shape[1:], a).ravel()[idx] for a in alphas]
    best = None
    for i in range(len(alphas)):
        for j in range(i + 1, len(alphas)):
            a = np.stack([np.ones(idx.size), gs[i], gs[j]], 1) * w[:, None]
            fits = [nnls(a, r[c] * w) for c in range(3)]
            err = sum(res ** 2 for _, res in fits)
            if best is None or err < best[0]:
                best = (err, (alphas[i], alphas[j]), np.array([x for x, _ in fits]))
    return best[1], best[2]


def lobe_table(shape, alpha, coef, denom=0):
    """b (3, n1, n2, n3) from one alpha (or a pair of them) and (3, 2 or 3) coefficients."""
    alphas = alpha if isinstance(alpha, tuple) else (alpha,)
    b = np.broadcast_to(coef[:, 0, None, None, None], (3, *shape)).astype(np.float64)
    for k, a in enumerate(alphas):
        b = b + coef[:, k + 1, None, None, None] * ggx(shape, a, denom)[None]
    return b


@contextlib.contextmanager
def coded_as(fn):
    """The encoder codes fn(brdf, transform, basis) instead of its own channels."""
    saved = enc_mod.coded_channels, fill_mod.coded_channels
    enc_mod.coded_channels = fill_mod.coded_channels = fn
    try:
        yield
    finally:
        enc_mod.coded_channels, fill_mod.coded_channels = saved


class BaseSparse:
    learns = False

    def __init__(self, eps: float = 0.03, denom: int = 1, ensemble: str = "",
                 n_coeffs: int = 262, tag: str = "", ff: float = 0.1, fix: int = 0,
                 g: float = 0.0, logfit: int = 0, cos: int = 0, sel: str = "",
                 fp: float = 1.0, lobes: int = 1):
        self.eps, self.denom, self.n = float(eps), int(denom), int(n_coeffs)
        self.ff, self.fp, self.fix, self.g = float(ff), float(fp), int(fix), float(g)
        self.logfit, self.cos, self.sel, self.lobes = int(logfit), int(cos), sel, int(lobes)
        self.ens = resolve_ensemble(ensemble or None)
        self.name = (f"base-e{eps:g}-d{denom}-f{ff:g}-{tag}-{n_coeffs}" + ("-fix" if fix else "")
                     + (f"-g{g:g}" if g else "") + ("-logfit" if logfit else "")
                     + ("-cos" if cos else "") + (f"-pair-{sel}" if sel else "")
                     + (f"-fp{fp:g}" if fp != 1 else "") + (f"-l{lobes}" if lobes != 1 else ""))

    def fit(self, brdfs):
        return self

    def _lobe(self, rho, valid, level):
        if self.lobes == 2:
            alpha, coef = fit_two_lobes(rho, valid, level, self.ff, self.fp)
            return lobe_table(rho.shape[1:], alpha, coef), alpha, coef
        if self.logfit:
            alpha, coef = fit_lobe_log(rho, valid, level, self.eps, self.denom)
        else:
            alpha, coef = fit_lobe(rho, valid, level, self.denom, self.ff, self.fp)
        return lobe_table(rho.shape[1:], alpha, coef, self.denom), alpha, coef

    def _one(self, brdf, cos):
        rho, valid = brdf.channel_first(), brdf.valid
        level = material_level(rho, valid)
        base, alpha, coef = self._lobe(rho, valid, level)
        f = self.eps * level
        cw = np.asarray(cosine_weight(rho.shape[1:]), np.float64) if cos else 1.0
        base = base * cw
        w = ((base + f) / level) ** self.g

        def channels(b, transform, basis):
            x = b.channel_first().astype(np.float64) * cw
            t = np.where(valid, np.log((np.maximum(x, 0) + f) / (base + f)) * w, 0)
            return to_basis(t.astype(np.float32), basis)

        with coded_as(channels):
            m = as_stored(encode(brdf, self.ens, n_coeffs=self.n, transform="log-level"))
        t = m.transformed(self.ens).astype(np.float64)
        dec = (np.maximum((base + f) * np.exp(np.clip(t / w, -50, 50)) - f, 0) / cw).astype(np.float32)
        nbytes = len(to_bytes(m)) + (14 if self.lobes == 1 else 22)  # the lobe as float16
        if self.fix:  # one scale per channel fitted to the cosine-weighted energy
            sw = (np.maximum(cosine_product(rho.shape[1:]), 0) * bin_solid_angle(rho.shape[1:]))[valid]
            d, r = dec[:, valid].astype(np.float64), rho[:, valid].astype(np.float64)
            s = (sw * d * r).sum(1) / np.maximum((sw * d * d).sum(1), 1e-30)
            dec = (dec * s[:, None, None, None]).astype(np.float32)
            nbytes += 6
        return Compact(self.name, nbytes, lambda: np.moveaxis(dec, 0, -1).copy(),
                       {"transform": "base-cos" if cos else "base", "level": level,
                        "alpha": alpha, "coef": coef.tolist()})

    def compress(self, brdf):
        if not self.sel:
            return self._one(brdf, self.cos)
        rho = brdf.channel_first()
        best = None
        for cos in (0, 1):
            c = self._one(brdf, cos)
            dec = np.moveaxis(c.reconstruct(), -1, 0)
            if self.sel == "render":
                e = render_proxy_error(rho, dec, valid=brdf.valid)
            else:
                e = gamma_mse(rho[:, brdf.valid], dec[:, brdf.valid])
            if best is None or e < best[0]:
                best = (e, c)
        return best[1]
