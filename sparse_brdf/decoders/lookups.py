"""numpy lookups of a sparse BRDF from the decoders' uploaded data: the Dr.Jit kernels'
twins (vectorised over N bins, for testing without a renderer) and the one-point lookups
of Mitsuba's scalar variants, one implementation for both.

In a scalar variant every BSDF call is its own Python call, and the kernels' per-float
Python loops (:func:`mitsuba_plugin.decoders.grouped_x`,
:func:`mitsuba_plugin.decoders.strict_x`) cost far more than the table lookup of
``tabulated_brdf``. Arranged as below, one lookup is a handful of numpy calls on the
same data, still evaluating only the sparse model's terms (docs/method.md):

- **grouped** (:class:`GroupedLookup`): the layout's row of the bin pair (ip, iq)
  (:func:`~sparse_brdf.decoders.layouts.grouped_layout`, ``L`` floats, read in place)
  against, per sum, the atom values at the bin of mode g under the floats that add to
  that sum (0 under the others; ``(4, L)`` floats per bin, built once):
  ``[X_0, X_1, X_2, cos_i cos_o] = values[ig] . table[pair]``.
- **strict** (:class:`StrictLookup`): every term's ``U1[i, a_t] U2[j, b_t] U3[k, c_t]``
  from the three modes' distinct atom rows, times its coefficient in its channel's
  row: ``X = coeffs . (r1[i][ia] * r2[j][ib] * r3[k][ic])``, ``coeffs`` (3, T).

How they contract matters as much as what: a numpy call costs about a microsecond, the
table's whole lookup about seven. The grouped lookups use ``ndarray.dot`` on the (4, L)
float32 block (a BLAS gemv, single-threaded at this size: 0.5 us against 0.85 us for the
``np.vecdot`` ufunc). The strict lookups and the N-bin evaluations keep ``np.vecdot``
(``np.einsum`` before numpy 2.0): ``dot`` gained nothing on the strict decoder's (3, T)
product, and an earlier build saw 10-40 us per larger BLAS product from the render
threads of a loaded machine. Measurements: docs/benchmarks.md, "Render speed per variant".

Colour basis: given the basis's matrix M^T (:func:`~sparse_brdf.decoders.layouts.
colour_mix`), the lookups fold it into ``values`` and ``coeffs`` (the rows of transformed
R, G, B are M^T times those of the coded channels), so one contraction gives the
transformed R, G, B; without it they give the coded channels, as the kernels do before
their mix.
"""

from __future__ import annotations

import numpy as np

from ..params import check_choice
from .buffers import mix_channels
from .layouts import (
    DECODERS,
    PACK_BITS,
    PACKET,
    SLOT,
    UNION_ATOMS,
    GroupedLayout,
    channel_terms,
    grouped_channels,
    grouped_layout,
    strict_channel,
)

#: ``a . b`` over the last axis, broadcasting the others (no BLAS: see the module docstring)
_vecdot = getattr(np, "vecdot", None) or (lambda a, b: np.einsum("...f,...f->...", a, b))


def _mixed(rows: np.ndarray, mix) -> np.ndarray:
    """Rows of coded channels (3, ...) as rows of transformed R, G, B: ``M^T rows`` for
    the colour basis's M^T ``mix`` (nested floats; None: unchanged)."""
    return rows if mix is None else np.tensordot(np.asarray(mix, np.float64), rows, axes=1)


class GroupedLookup:
    """The grouped decoder's uploaded layout (:class:`~sparse_brdf.decoders.layouts.
    GroupedLayout`) as one product per lookup (see the module docstring).

    Attributes
    ----------
    tables : np.ndarray
        (n_p * n_q, L) float32: the layout's rows, per bin pair, read in place.
    values : np.ndarray
        (n_g, 4, L) float32: per bin of mode g and per sum (the three channels: coded, or
        transformed R, G, B when built with the basis's mix; then the bin's ``cos_i
        cos_o``), the atom value (or the weight's atom factor) that multiplies each
        float of a table row adding to that sum, 0 under the other floats.
    modes : tuple of int
        (p, q, g): the contracted modes and the grouped one.
    n_q : int
        Size of mode q (the table's row stride in bin pairs).
    point : callable
        ``point(i, j, k)``: :meth:`eval` at one bin (Python ints), in float32 like the
        kernel, as a list of 4 floats (a closure over the arrays: it runs once per BSDF
        call in the scalar variants).
    """

    def __init__(self, layout: GroupedLayout, ch, mix=None, tables=None) -> None:
        """``layout`` with the modes of channel ``ch`` (a
        :class:`~sparse_brdf.decoders.layouts.GroupedChannel`); ``mix``: the colour
        basis's M^T (folded into ``values``); ``tables``: the layout's tables as already
        held (e.g. the buffer a plugin uploaded), read instead of ``layout.tables``."""
        flat = layout.tables if tables is None else tables
        n_g = ch.rows.shape[1]
        n = layout.chunks
        if layout.kind == "slots":
            width = n * PACKET  # float 4 s + c: channel c's column s (c = 3: the weight)
            values = layout.values.reshape(n_g, width)
            sums = np.arange(width) % SLOT
        else:
            # chunk u: floats 3 a + c (atom a, channel c) and 15 (the weight); the atom
            # values' chunk: the 5 atoms' values, then the weight's factor (float 5)
            width = n * (3 * UNION_ATOMS + 1)
            pos = np.arange(width) % (3 * UNION_ATOMS + 1)
            chunk = np.arange(width) // (3 * UNION_ATOMS + 1)
            weight = pos == 3 * UNION_ATOMS
            src = chunk * PACKET + np.where(weight, UNION_ATOMS, pos // 3)
            values = layout.values.reshape(n_g, n * PACKET)[:, src]
            sums = np.where(weight, 3, pos % 3)
        select = np.zeros((4, width))  # which sum each float of a table row adds to
        select[sums, np.arange(width)] = 1.0
        select[:3] = _mixed(select[:3], mix)
        self.tables = flat.reshape(-1, width)
        # float32 like the tables and the kernel (the mix matrix's entries are float32
        # numbers, colour_mix: a mixed value is rounded once)
        self.values = (select[None] * values[:, None, :].astype(np.float64)).astype(np.float32)
        self.modes = (ch.mode_p, ch.mode_q, ch.mode_g)
        self.n_q = int(ch.n_q)
        self.point = _grouped_point(self.tables, self.values, self.modes, self.n_q)

    def eval(self, bins) -> np.ndarray:
        """(N, 4) sums at integer bins ``bins`` = (i, j, k) (arrays of N): the three
        channels' X and the bins' ``cos_i cos_o``."""
        p, q, g = self.modes
        pair = np.asarray(bins[p]) * self.n_q + np.asarray(bins[q])
        return _vecdot(self.values[np.asarray(bins[g])].astype(np.float64),
                       self.tables[pair][:, None, :].astype(np.float64))

    def point_linear(self, lin) -> list:
        """The sums interpolated trilinearly at one point: ``lin`` per mode (i0, i1, t),
        the two neighbouring samples and the weight of i1 (as
        :func:`mitsuba_plugin.kernels.linear_bins` gives them); the table rows of the four
        bin pairs and the atom values of the two bins of mode g are blended, then
        multiplied, as the kernel does. A list of 4 floats."""
        p, q, g = self.modes
        (p0, p1, tp), (q0, q1, tq), (g0, g1, tg) = lin[p], lin[q], lin[g]
        nq = self.n_q
        rows = self.tables[[p0 * nq + q0, p0 * nq + q1, p1 * nq + q0, p1 * nq + q1]]
        wts = np.array([(1.0 - tp) * (1.0 - tq), (1.0 - tp) * tq, tp * (1.0 - tq), tp * tq],
                       np.float32)
        vals = (1.0 - tg) * self.values[g0] + tg * self.values[g1]
        return vals.dot(wts.dot(rows)).tolist()


def _grouped_point(tables, values, modes, n_q):
    """:attr:`GroupedLookup.point` of these arrays, modes (p, q, g) and stride ``n_q``."""
    p, q, g = modes

    def point(i: int, j: int, k: int) -> list:
        b = (i, j, k)
        return values[b[g]].dot(tables[b[p] * n_q + b[q]]).tolist()

    return point


class StrictLookup:
    """The strict decoder's channels (:class:`~sparse_brdf.decoders.layouts.StrictChannel`)
    as one product per lookup (see the module docstring).

    Attributes
    ----------
    rows : tuple of np.ndarray
        Per mode m, (n_m, K_m) float64: the distinct atom columns of every channel (one
        after the other), one grid bin per row.
    index : tuple of np.ndarray
        Per mode, (T,) int64: each term's column in ``rows[m]`` (T: the terms of all the
        channels).
    coeffs : np.ndarray
        (3, T) float64: each term's coefficient in its channel's row (coded channels, or
        transformed R, G, B when built with the basis's mix), 0 in the others.
    """

    def __init__(self, chans, mix=None) -> None:
        """The strict data ``chans`` of the channels (one to three) and the colour
        basis's M^T ``mix`` (None: the coded channels)."""
        mask = (1 << PACK_BITS) - 1
        rows, index = [], []
        for m in range(3):
            offs = np.cumsum([0] + [ch.rows[m].shape[0] for ch in chans])
            rows.append(np.ascontiguousarray(
                np.concatenate([ch.rows[m] for ch in chans]).T, np.float64))
            index.append(np.concatenate(
                [((ch.packed.astype(np.int64) >> (m * PACK_BITS)) & mask) + offs[c]
                 for c, ch in enumerate(chans)]))
        coeffs = np.zeros((3, sum(ch.n_terms for ch in chans)))
        start = 0
        for c, ch in enumerate(chans):
            coeffs[c, start:start + ch.n_terms] = ch.values
            start += ch.n_terms
        self.rows, self.index = tuple(rows), tuple(index)
        self.coeffs = _mixed(coeffs, mix)

    def eval(self, bins) -> np.ndarray:
        """(N, 3) X of the channels at integer bins ``bins`` = (i, j, k) (arrays of N)."""
        (r1, r2, r3), (ia, ib, ic) = self.rows, self.index
        i, j, k = (np.asarray(b) for b in bins)
        return (r1[i][:, ia] * r2[j][:, ib] * r3[k][:, ic]) @ self.coeffs.T

    def point(self, i: int, j: int, k: int) -> list:
        """:meth:`eval` at one bin (Python ints): a list of 3 floats."""
        (r1, r2, r3), (ia, ib, ic) = self.rows, self.index
        return _vecdot(self.coeffs, r1[i][ia] * r2[j][ib] * r3[k][ic]).tolist()

    def point_linear(self, lin) -> list:
        """X interpolated trilinearly at one point (``lin`` as for
        :meth:`GroupedLookup.point_linear`): each mode's atom rows interpolated linearly,
        as the kernel does. A list of 3 floats."""
        prod = 1.0
        for r, idx, (i0, i1, t) in zip(self.rows, self.index, lin, strict=True):
            prod = prod * ((1.0 - t) * r[i0][idx] + t * r[i1][idx])
        return _vecdot(self.coeffs, prod).tolist()


# ----------------------------------------------------------------------- numpy mirrors


def layout_eval(layout: GroupedLayout, ch, bins):
    """(X of the three channels (3, N), cos_i cos_o (N,)) at integer bins from an
    uploaded layout (numpy mirror of the kernel, :class:`GroupedLookup`)."""
    out = GroupedLookup(layout, ch).eval(bins)
    return out[:, :3].T, out[:, 3]


def strict_eval(ch, bins) -> np.ndarray:
    """X at integer bins from a strict channel (numpy mirror of the kernel,
    :class:`StrictLookup`)."""
    return StrictLookup([ch]).eval(bins)[:, 0]


def model_x(model, ensemble, bins, decoder: str = "grouped",
            kind: str | None = None) -> np.ndarray:
    """Transformed R, G, B (3, N) of ``model`` at integer bins (i, j, k), as the plugin's
    ``decoder`` computes them at the nearest bin: the three coded channels from the
    uploaded data (grouped: the layout ``kind``, default the automatic one), then the
    colour mix of the model's basis (numpy mirror of the whole lookup before the inverse
    transform)."""
    if decoder == "grouped":
        chans = grouped_channels(model, ensemble)
        xs, _ = layout_eval(grouped_layout(chans, tuple(model.shape), kind), chans[0], bins)
    elif decoder == "strict":
        xs = np.stack([strict_eval(strict_channel(*channel_terms(model, ensemble, c)), bins)
                       for c in range(3)])
    else:
        check_choice("decoder", decoder, DECODERS[:2])
    return mix_channels(xs, model.basis)
