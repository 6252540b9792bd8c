"""The sparse model's two decoders as Dr.Jit kernels: X of a coded channel at a direction
pair's bin (or interpolated), read from per-material buffers without building the
tensor (docs/method.md).

- grouped (:func:`grouped_x`): terms grouped by the atom of one mode, the other two
  modes contracted at load time into a table of bin pairs; one loop per layout
  ("slots" or "union"), in one kernel.
- strict (:func:`strict_x`): one loop over the nonzero terms, closing partial sums at
  the ends of their groups; also the derivative carrier of differentiable renders.
- pair (:func:`pair_x`): a library's materials (``sparse_library``), the material
  picked per lane; one loop over the lane's material's (b, c) pairs of atoms.

The buffers (:class:`GroupedBuffers`, :class:`StrictBuffers`) are uploaded from the
numpy layouts of :mod:`sparse_brdf.decoders.layouts`, as opaque Dr.Jit scalars, so every
material shares one compiled kernel; :mod:`sparse_brdf.decoders.lookups` holds the numpy
twins of both kernels.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import drjit as dr

from sparse_brdf.decoders.layouts import END_B, END_C, PACK_BITS, PACKET, SLOT, UNION_ATOMS
from sparse_brdf.decoders.library import HEADER_U
from sparse_brdf.decoders.scene import ensemble_rows

from .kernels import Ops, Shape

# ---------------------------------------------------------------- grouped decoder kernel


@dataclass
class GroupedBuffers:
    """The grouped decoder's per-material data as the kernel reads it (from a
    :class:`sparse_brdf.decoders.layouts.GroupedLayout`); numbers are opaque Dr.Jit scalars."""

    tables: object  # Float: per bin pair (ip, iq), ``chunks`` chunks of table floats
    values: object  # Float: per bin of mode g, ``chunks`` chunks of atom values
    chunks: dict  # {"slots": n, "union": n}: the material's layout has n > 0, the other 0
    sel: list  # for modes (p, q, g): three 0/1 UInt32 that pick that mode's bin index
    fsel: list  # the same as Floats, to pick that mode's interpolation weight
    n_q: object  # UInt32: the size of mode q (the table's row stride in bin pairs)
    #: (first packet of the material's tables, of its atom values) in shared buffers (a
    #: library's, per lane); None: the buffers are the material's own
    base: tuple | None = None


def upload_grouped(ops: Ops, lay, ch) -> GroupedBuffers:
    """:class:`GroupedBuffers` of layout ``lay``, whose channels' modes are those of
    ``ch`` (a :class:`~sparse_brdf.decoders.layouts.GroupedChannel`)."""
    tables = ops.floats(lay.tables)
    values = ops.floats(lay.values)
    # one kernel for both layouts: a loop for each, the other runs 0 times
    chunks = {k: ops.u(lay.chunks if k == lay.kind else 0) for k in ("slots", "union")}
    modes = (ch.mode_p, ch.mode_q, ch.mode_g)
    sel = [[ops.u(int(mode == s)) for mode in range(3)] for s in modes]
    fsel = [[ops.f(float(mode == s)) for mode in range(3)] for s in modes]
    return GroupedBuffers(tables, values, chunks, sel, fsel, ops.u(ch.n_q))


def _pick(idx, sel):
    """``idx[mode]`` for the mode whose entry of ``sel`` (three 0/1 values) is 1: no
    Python branch on per-material data, so one kernel serves every grouped mode."""
    return idx[0] * sel[0] + idx[1] * sel[1] + idx[2] * sel[2]


def _grouped_rows(buf: GroupedBuffers, bins, lin):
    """([(bin pair, weight)], [(bin of mode g, weight)]) a lookup reads: one of each with
    weight None at the nearest bin (``bins``), or the 4 bin pairs and 2 bins of mode g
    around the point with their interpolation weights (``lin``, bins is None)."""
    nq = buf.n_q
    sel_p, sel_q, sel_g = buf.sel
    if lin is None:
        return ([(_pick(bins, sel_p) * nq + _pick(bins, sel_q), None)],
                [(_pick(bins, sel_g), None)])
    i0s = tuple(x[0] for x in lin)
    i1s = tuple(x[1] for x in lin)
    ts = tuple(x[2] for x in lin)
    fp, fq, fg = buf.fsel
    tp, tq, tg = _pick(ts, fp), _pick(ts, fq), _pick(ts, fg)
    pairs = [(ep * nq + eq, wp * wq)
             for ep, wp in ((_pick(i0s, sel_p), 1.0 - tp), (_pick(i1s, sel_p), tp))
             for eq, wq in ((_pick(i0s, sel_q), 1.0 - tq), (_pick(i1s, sel_q), tq))]
    gs = [(_pick(i0s, sel_g), 1.0 - tg), (_pick(i1s, sel_g), tg)]
    return pairs, gs


def _blend(ops: Ops, buf, rows, stride, h, active, base=None):
    """Packet h of each of ``rows`` [(row index, weight)] of ``buf`` (a row is
    ``stride`` packets, the first at packet ``base``, None: 0), summed with the
    weights; a weight of None: that row alone."""
    out = None
    for row, wt in rows:
        at = row * stride + h
        pk = ops.gather_packet(buf, at if base is None else at + base, PACKET, active)
        if wt is None:
            return list(pk)
        pk = [wt * x for x in pk]
        out = pk if out is None else [a + b for a, b in zip(out, pk, strict=True)]
    return out


def _fma(ops: Ops, a, b, c):
    return dr.fma(a, b, c) if ops.jit else a * b + c


def _union_chunk(ops: Ops, tv, vv, acc):
    """Add one union chunk: table floats ``tv`` (3 a + c: channel c at atom a < 5; 15:
    the weight) times atom values ``vv`` (a: atom a; 5: the weight) to the four sums."""
    out = list(acc)
    for a in range(UNION_ATOMS):
        for c in range(3):
            out[c] = _fma(ops, tv[3 * a + c], vv[a], out[c])
    out[3] = _fma(ops, tv[3 * UNION_ATOMS], vv[UNION_ATOMS], out[3])
    return tuple(out)


def grouped_x(ops: Ops, buf: GroupedBuffers, bins, lin, active):
    """X of the three channels and the bins' cos_i cos_o from the shared rows (see
    :func:`sparse_brdf.decoders.layouts.grouped_layout`; its numpy twin is
    :func:`~sparse_brdf.decoders.lookups.layout_eval`). Two loops, one per layout; a
    material's data has one of them, and the other's count is 0.

    slots: a chunk is one packet of table row and one of atom values, float 4 s + c of
    both belonging to channel c (c = 3: the weight): one multiply-add sum per float.
    union: a chunk is two packets of table row and one of atom values
    (:func:`_union_chunk`)."""
    n_s, n_u = buf.chunks["slots"], buf.chunks["union"]
    pairs, gs = _grouped_rows(buf, bins, lin)
    t_buf, v_buf = buf.tables, buf.values
    tb, vb = (None, None) if buf.base is None else buf.base

    def body_slots(h, acc):
        tv = _blend(ops, t_buf, pairs, n_s, h, active, tb)
        vv = _blend(ops, v_buf, gs, n_s, h, active, vb)
        return tuple(_fma(ops, a, b, c) for a, b, c in zip(tv, vv, acc, strict=True))

    def body_union(h, acc):
        tv = (_blend(ops, t_buf, pairs, 2 * n_u, 2 * h, active, tb)
              + _blend(ops, t_buf, pairs, 2 * n_u, 2 * h + 1, active, tb))
        return _union_chunk(ops, tv, _blend(ops, v_buf, gs, n_u, h, active, vb), acc)

    zero = ops.m.Float(0.0) if ops.jit else 0.0
    acc_s = ops.loop(n_s, body_slots, (zero,) * PACKET)
    acc_u = ops.loop(n_u, body_union, (zero,) * SLOT)
    sums = [sum(acc_s[c::SLOT], acc_u[c]) for c in range(SLOT)]
    return sums[:3], sums[3]


# ----------------------------------------------------------------- strict decoder kernel

# The ensembles' atom rows as uploaded, one per variant (its ``Ops``) and ensemble id:
# every strict-decoded material of a scene reads the one copy.
_SHARED: dict = {}
_SHARED_LOCK = threading.Lock()


def shared_rows(ops: Ops, ensemble):
    """(the ensemble's :class:`~sparse_brdf.decoders.scene.SharedRows`, its rows as a
    Float buffer of variant ``ops``), uploaded once per variant and ensemble (the last
    ensemble of each variant is kept)."""
    key = (ops, ensemble.id)
    with _SHARED_LOCK:
        hit = _SHARED.get(key)
        if hit is None:
            rows = ensemble_rows(ensemble)
            hit = (rows, ops.floats(rows.rows))
            for k in [k for k in _SHARED if k[0] is ops]:
                del _SHARED[k]
            _SHARED[key] = hit
    return hit



@dataclass
class StrictBuffers:
    """The strict decoder's per-material data as the kernel reads it (from a
    :class:`sparse_brdf.decoders.layouts.StrictLayout`); numbers are opaque Dr.Jit scalars."""

    values: object  # Float: the coefficients s of every channel's terms
    packed: object  # UInt32: their packed atom indices and group-end flags
    rows: object  # Float: the distinct atom rows, per channel and mode
    channels: list  # per channel {"t": terms, "soff": first term, "roff": [row offset]}


def upload_strict(ops: Ops, lay, rows=None) -> StrictBuffers:
    """:class:`StrictBuffers` of layout ``lay``; ``rows``: a Float buffer of atom rows
    that ``lay``'s row offsets point into (the ensemble's, :func:`shared_rows`) instead
    of the layout's own."""
    # a buffer is never empty (a material without coefficients): Dr.Jit refuses to trace
    # a gather from an empty array, even one a zero-trip loop never runs
    values = ops.floats(lay.values if len(lay.values) else [0.0])
    packed = ops.uints(lay.packed if len(lay.packed) else [0])
    if rows is None:
        rows = ops.floats(lay.rows if len(lay.rows) else [0.0])
    per = [{"t": ops.u(t), "soff": ops.u(soff), "roff": [ops.u(r) for r in roff]}
           for t, soff, roff in zip(lay.n_terms, lay.term_offsets, lay.row_offsets,
                                    strict=True)]
    return StrictBuffers(values, packed, rows, per)


def strict_x(ops: Ops, buf: StrictBuffers, shape: Shape, c: int, bins, lin, active,
             grad=None):
    """X of channel ``c``: one loop over its terms, sorted by (c, b, a), evaluating
    ``sum_c U3[k, c] sum_b U2[j, b] sum_a s U1[i, a]``; the partial sums are closed at
    the flagged ends of each b-group and c-group, so U2 and U3 are read once per group
    (numpy twin: :func:`~sparse_brdf.decoders.lookups.strict_eval`). At the nearest bin
    (``bins``) or interpolated (``lin``, bins is None).

    ``grad`` = (values, order): instead, the derivative carrier
    ``sum_t (s_t - detach(s_t)) U1[i, a_t] U2[j, b_t] U3[k, c_t]``, zero in value, with
    ``s_t = values[order[t]]`` read from the differentiable values themselves (a
    sum-style loop, which Dr.Jit differentiates in both modes)."""
    sp = buf.channels[c]
    n = shape.n
    s_buf, p_buf, r_buf = buf.values, buf.packed, buf.rows
    soff, roff = sp["soff"], sp["roff"]
    mask = (1 << PACK_BITS) - 1
    zero = ops.m.Float(0.0)

    if lin is None:
        def row(mode, a, active_):
            return ops.gather(r_buf, roff[mode] + a * n[mode] + bins[mode], active_)
    else:
        def row(mode, a, active_):
            i0, i1, w = lin[mode]
            base = roff[mode] + a * n[mode]
            return ((1.0 - w) * ops.gather(r_buf, base + i0, active_)
                    + w * ops.gather(r_buf, base + i1, active_))

    def body(t, state):
        acc, acc_c, acc_b = state
        p = ops.gather_u(p_buf, soff + t, active)
        s = ops.gather(s_buf, soff + t, active)
        end_b = (p & END_B) != 0
        end_c = (p & END_C) != 0
        acc_b = acc_b + s * row(0, p & mask, active)
        # close the (c, b) group: multiply by U2[j, b] (read only at group ends)
        u2 = row(1, (p >> PACK_BITS) & mask, active & end_b)
        acc_c = dr.select(end_b, acc_c + acc_b * u2, acc_c)
        acc_b = dr.select(end_b, zero, acc_b)
        # close the c group: multiply by U3[k, c]
        u3 = row(2, (p >> (2 * PACK_BITS)) & mask, active & end_c)
        acc = dr.select(end_c, acc + acc_c * u3, acc)
        acc_c = dr.select(end_c, zero, acc_c)
        return acc, acc_c, acc_b

    def body_grad(t, state):
        values, order = grad
        p = ops.gather_u(p_buf, soff + t, active)
        s = ops.gather(values, ops.gather_u(order, t, active), active)
        term = ((s - dr.detach(s)) * row(0, p & mask, active)
                * row(1, (p >> PACK_BITS) & mask, active)
                * row(2, (p >> (2 * PACK_BITS)) & mask, active))
        return (state[0] + term,)

    if grad is not None:
        return ops.loop(sp["t"], body_grad, (zero,), sum_style=True)[0]
    return ops.loop(sp["t"], body, (zero, zero, zero))[0]


# ------------------------------------------------------------------- pair decoder kernel


@dataclass
class PairBuffers:
    """A library's materials as the pair decoder reads them (from
    :mod:`sparse_brdf.decoders.library`): every material's pair tables and packed atoms,
    their per-material headers, and the ensemble's shared rows."""

    tables: object  # Float: per pair, n1 floats (T_bc at each bin of mode 1)
    packed: object  # UInt32: per pair, b | c << PACK_BITS
    header_u: object  # UInt32: per material, HEADER_U
    header_f: object  # Float: per material, HEADER_F
    rows: object  # Float: the ensemble's atom rows (shared_rows)
    n1: object  # UInt32: the table's row length


def upload_pairs(ops: Ops, tables, packed, header, rows, n1: int) -> PairBuffers:
    """:class:`PairBuffers` of a library's pair ``tables`` and ``packed`` atoms
    (:func:`~sparse_brdf.decoders.library.pair_buffers`) and its ``header``, reading
    ``rows`` (the shared rows' Float buffer)."""
    return PairBuffers(ops.floats(tables), ops.uints(packed), ops.uints(header.u.ravel()),
                       ops.floats(header.f.ravel()), rows, ops.u(n1))


def pair_x(ops: Ops, buf: PairBuffers, shape: Shape, mat, bins, lin, active) -> list:
    """X of the three coded channels of material ``mat`` (per lane): per channel one
    loop over the material's (b, c) pairs, ``sum T_bc[i] U2[j, b] U3[k, c]``, its trip
    count the lane's material's (numpy twin:
    :class:`~sparse_brdf.decoders.library.PairLookup`). At the nearest bin (``bins``) or
    interpolated (``lin``, bins is None: each mode's values linearly)."""
    n = shape.n
    mask = (1 << PACK_BITS) - 1
    t_buf, p_buf, r_buf = buf.tables, buf.packed, buf.rows

    def read(b, base, mode, act):
        if lin is None:
            return ops.gather(b, base + bins[mode], act)
        i0, i1, w = lin[mode]
        return (1.0 - w) * ops.gather(b, base + i0, act) + w * ops.gather(b, base + i1, act)

    # the material's tables are an (n1, P) block from its first pair's n1-th float: pair e
    # at bin i is float base n1 + i P + (e - base) (sparse_brdf.decoders.library)
    first = ops.gather_u(buf.header_u, mat * HEADER_U + 12, active)
    total = ops.gather_u(buf.header_u, mat * HEADER_U + 13, active)
    t_rows = [first * (buf.n1 - 1) + b * total
              for b in ((bins[0],) if lin is None else lin[0][:2])]

    def read_t(e, act):
        if lin is None:
            return ops.gather(t_buf, t_rows[0] + e, act)
        w = lin[0][2]
        return ((1.0 - w) * ops.gather(t_buf, t_rows[0] + e, act)
                + w * ops.gather(t_buf, t_rows[1] + e, act))

    xs = []
    for c in range(3):
        h = mat * HEADER_U + 4 * c
        start, count, r2, r3 = (ops.gather_u(buf.header_u, h + f, active) for f in range(4))

        def body(t, acc, start=start, r2=r2, r3=r3):
            e = start + t
            p = ops.gather_u(p_buf, e, active)
            v = read_t(e, active) * read(r_buf, r2 + (p & mask) * n[1], 1, active)
            return (_fma(ops, v, read(r_buf, r3 + (p >> PACK_BITS) * n[2], 2, active),
                         acc[0]),)

        zero = ops.m.Float(0.0) if ops.jit else 0.0
        xs.append(ops.loop(count, body, (zero,))[0])
    return xs


def lane_grouped(ops: Ops, tables, values, header_u, mat, active) -> GroupedBuffers:
    """:class:`GroupedBuffers` of each lane's library material ``mat`` (its header's
    columns 14-21, :data:`~sparse_brdf.decoders.library.HEADER_U`): the library's grouped
    ``tables`` and ``values`` from the material's first packets, its chunks (0 for a
    material on the pair decoder: :func:`grouped_x` then adds nothing), modes and n_q."""
    h = mat * HEADER_U + 14
    t0, v0, n_s, n_u, mp, mq, mg, nq = (ops.gather_u(header_u, h + f, active)
                                        for f in range(8))
    m = ops.m
    sel = [[dr.select(mode == s, m.UInt32(1), m.UInt32(0)) for s in range(3)]
           for mode in (mp, mq, mg)]
    fsel = [[dr.select(mode == s, m.Float(1.0), m.Float(0.0)) for s in range(3)]
            for mode in (mp, mq, mg)]
    return GroupedBuffers(tables, values, {"slots": n_s, "union": n_u}, sel, fsel, nq,
                          (t0, v0))
