"""A library of sparse materials in one set of buffers: the pair decoder, which serves
many materials from one BSDF (``sparse_library``), the material picked per lookup.

Mitsuba traces every BSDF instance of a scene on every render, so a scene of a thousand
``sparse_brdf`` materials spends most of a render tracing them
(docs/records/many-materials-trace-2026-12-07.md). A library holds its materials' data
in shared buffers, indexed by material, and is traced once.

**The pair decoder.** Channel c of a material is ``X = sum_t s_t U1[i, a_t] U2[j, b_t]
U3[k, c_t]`` (docs/method.md). Grouping its terms by their (b, c) pair of atoms and
contracting mode 1 at load time, ``T_bc = sum_{t: (b_t, c_t) = (b, c)} s_t U1[:, a_t]``
(n1 floats per pair), a lookup is ``X = sum_pairs T_bc[i] U2[j, b] U3[k, c]``: one step
per pair (80-120 pairs per material for 650-850 terms: several times fewer steps than
the strict decoder), reading U2 and U3 from the ensemble's rows that every material
shares (:func:`~sparse_brdf.decoders.scene.ensemble_rows`). A material holds its pair
tables and one packed index per pair: 4 (n1 + 1) bytes per pair, about 45 kB.

The per-material header (:class:`PairHeader`) says where each channel's pairs start,
how many there are, where its dictionary's U2 and U3 rows start, the transform's
weight (cosine or not, scale) and the colour basis's mix. :class:`PairLookup` is the
numpy twin of the kernel (:func:`mitsuba_plugin.decoders.pair_x`) and the scalar
variants' one-point lookup.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..transforms import floor_value, material_scale, uses_cosine
from .buffers import colour_mix
from .layouts import PACK_BITS, PACKET, channel_terms, grouped_channels, grouped_layout
from .lookups import GroupedLookup
from .scene import SharedRows

#: Per material, the unsigned header: per channel (first pair, pairs, U2 row offset, U3
#: row offset), then the material's first pair and its pairs in all; then, for a
#: material on the grouped decoder (:func:`grouped_blocks`; 0 otherwise), the first
#: packet of its tables and of its atom values, its chunks in the slot and the union
#: layout (one of them 0), its modes p, q, g and n_q.
HEADER_U = 22
#: Per material, the float header: cosine weight (1 or 0), the weight's scale, the
#: colour basis's M^T (9 floats, row-major; the identity for "rgb"), the sampling
#: lobe's exponent and probability, then whether the material has a base lobe (a lobe
#: transform: 1, else 0) and the base lobe (alpha, kd R, G, B, ks R, G, B; 0 without),
#: then the value below which the material decodes as 0 (a floor transform's f L, 1/sr;
#: 0 without).
HEADER_F = 22


@dataclass(frozen=True)
class MaterialPairs:
    """One material's pair tables (see the module docstring).

    Attributes
    ----------
    tables : np.ndarray
        (P, n1) float32: ``T_bc`` of each of the material's pairs, channel by channel.
    packed : np.ndarray
        (P,) uint32: each pair's atoms ``b | c << PACK_BITS`` (their columns in the
        channel's dictionary).
    counts : tuple of int
        Pairs per channel (P in all).
    row_offsets : tuple of tuple of int
        Per channel, the first float of its dictionary's U2 and U3 rows in the shared rows.
    """

    tables: np.ndarray
    packed: np.ndarray
    counts: tuple
    row_offsets: tuple

    @property
    def nbytes(self) -> int:
        return int(self.tables.nbytes + self.packed.nbytes)


def pair_counts(model) -> tuple[int, int, int]:
    """The number of distinct (b, c) pairs of atoms of each of ``model``'s channels."""
    out = []
    for c in range(3):
        _, b, k = model.modes(c)
        out.append(int(np.unique(np.asarray(b, np.int64) << 32
                                 | np.asarray(k, np.int64)).size))
    return tuple(out)


def material_pairs(model, ensemble, shared: SharedRows) -> MaterialPairs:
    """The :class:`MaterialPairs` of ``model`` (checked against ``ensemble``), whose U2
    and U3 rows are read from ``shared`` (the ensemble's rows).

    Raises
    ------
    ValueError
        A dictionary has more than ``2**PACK_BITS - 1`` atoms in mode 2 or 3.
    """
    mask = (1 << PACK_BITS) - 1
    tables, packed, counts, offsets = [], [], [], []
    for c in range(3):
        s, (a, b, k), us = channel_terms(model, ensemble, c)
        if max(us[1].shape[1], us[2].shape[1]) > mask:
            raise ValueError(f"a dictionary has more than {mask} atoms in mode 2 or 3: the "
                             f"pair decoder packs at most {mask}")
        keys, inv = np.unique(b << 32 | k, return_inverse=True)
        t = np.zeros((keys.size, us[0].shape[0]), np.float64)
        np.add.at(t, inv, (us[0][:, a] * s.astype(np.float64)).T)
        tables.append(t.astype(np.float32))
        packed.append(((keys >> 32) | ((keys & 0xFFFFFFFF) << PACK_BITS)).astype(np.uint32))
        counts.append(int(keys.size))
        d = int(model.dict_index[c])
        offsets.append((int(shared.offsets[d, 1]), int(shared.offsets[d, 2])))
    return MaterialPairs(np.concatenate(tables), np.concatenate(packed), tuple(counts),
                         tuple(offsets))


@dataclass(frozen=True)
class PairHeader:
    """The per-material headers of a library (see the module docstring): ``u`` (M,
    :data:`HEADER_U`) uint32 and ``f`` (M, :data:`HEADER_F`) float32."""

    u: np.ndarray
    f: np.ndarray

    @property
    def nbytes(self) -> int:
        return int(self.u.nbytes + self.f.nbytes)

    @property
    def n_pairs(self) -> int:
        """The pairs of every material and channel."""
        return int(self.u[:, 13].sum())


def pair_header(models, shared: SharedRows, lobes=None, grouped=None) -> PairHeader:
    """The :class:`PairHeader` of ``models``, whose pairs (:func:`material_pairs`) are
    stored one after the other in that order and whose U2 and U3 rows are read from
    ``shared``; ``lobes``: each material's (exponent, probability) of the sampling lobe
    (default: (1, 0), cosine sampling); ``grouped``: per material, its
    :class:`GroupedBlock` (:func:`grouped_blocks`) or None: a material on the grouped
    decoder has no pairs."""
    u = np.zeros((len(models), HEADER_U), np.uint32)
    f = np.zeros((len(models), HEADER_F), np.float32)
    start = 0
    for m, model in enumerate(models):
        block = None if grouped is None else grouped[m]
        counts = (0, 0, 0) if block is not None else pair_counts(model)
        if block is not None:
            u[m, 14:22] = block.header()
        u[m, 12:14] = (start, sum(counts))
        for c, n in enumerate(counts):
            d = int(model.dict_index[c])
            u[m, 4 * c:4 * c + 4] = (start, n, shared.offsets[d, 1], shared.offsets[d, 2])
            start += n
        mix = colour_mix(model.basis)
        f[m, 0] = 1.0 if uses_cosine(model.transform) else 0.0
        f[m, 1] = material_scale(model.transform, model.gain)  # a level file: its own gain
        f[m, 2:11] = np.eye(3).ravel() if mix is None else np.asarray(mix).ravel()
        f[m, 11:13] = (1.0, 0.0) if lobes is None else lobes[m]
        if model.lobe is not None:
            f[m, 13], f[m, 14:21] = 1.0, model.lobe
        f[m, 21] = floor_value(model.floor, model.gain)
    return PairHeader(u, f)


def pair_buffers(models, ensemble, shared: SharedRows, n_pairs: int, grouped=None):
    """(tables, packed): every material's pair tables, flat float32 (``n_pairs`` n1), and
    packed atoms, uint32 (``n_pairs``), in the order of ``models`` (as
    :func:`pair_header` counts them). A material's P pairs are an (n1, P) block, bin by
    bin (a lookup then reads its pairs' values at one bin from consecutive floats: a few
    cache lines instead of one a pair). Written material by material into one array,
    so that building a library holds one material's tables besides."""
    n1 = int(models[0].shape[0]) if models else 1
    tables = np.empty(max(n_pairs * n1, 1), np.float32)
    packed = np.zeros(max(n_pairs, 1), np.uint32)
    at = 0
    for m, model in enumerate(models):
        if grouped is not None and grouped[m] is not None:
            continue  # on the grouped decoder: no pairs
        mp = material_pairs(model, ensemble, shared)
        p = mp.packed.size
        tables[at * n1:(at + p) * n1] = mp.tables.T.ravel()
        packed[at:at + p] = mp.packed
        at += p
    if at != n_pairs:
        raise ValueError(f"the materials hold {at} pairs, their header {n_pairs}")
    return tables, packed


@dataclass(frozen=True)
class GroupedBlock:
    """A library material on the grouped decoder: its layout and channels
    (:func:`~sparse_brdf.decoders.layouts.grouped_layout`) and where its tables and atom
    values start in the library's buffers, in packets of ``PACKET`` floats."""

    layout: object
    channel: object
    table_packet: int
    value_packet: int

    def header(self) -> tuple:
        """Columns 14-21 of the material's :data:`HEADER_U` header."""
        lay, ch = self.layout, self.channel
        slots, union = (lay.chunks, 0) if lay.kind == "slots" else (0, lay.chunks)
        return (self.table_packet, self.value_packet, slots, union, ch.mode_p, ch.mode_q,
                ch.mode_g, ch.n_q)


def grouped_blocks(models, ensemble, plans, chosen):
    """(tables, values, blocks): the grouped decoder's data of the materials ``chosen``
    (booleans, one per model; ``plans``: their
    :func:`~sparse_brdf.decoders.layouts.grouped_plan`), flat float32 buffers with each
    material's block whole packets long, and per material its :class:`GroupedBlock` or
    None."""
    tables, values, blocks, at_t, at_v = [], [], [], 0, 0
    for model, plan, on in zip(models, plans, chosen, strict=True):
        if not on:
            blocks.append(None)
            continue
        chans = grouped_channels(model, ensemble, plan.mode)
        lay = grouped_layout(chans, tuple(model.shape), plan.kind)
        blocks.append(GroupedBlock(lay, chans[0], at_t, at_v))
        for buf, flat in ((tables, lay.tables), (values, lay.values)):
            pad = -flat.size % PACKET
            buf.append(np.concatenate([flat, np.zeros(pad, np.float32)]) if pad else flat)
        at_t += tables[-1].size // PACKET
        at_v += values[-1].size // PACKET
    empty = [np.zeros(PACKET, np.float32)]
    return np.concatenate(tables or empty), np.concatenate(values or empty), blocks


class PairLookup:
    """The pair decoder in numpy: the kernel's twin, vectorised over N bins
    (:meth:`eval`), and the scalar variants' one-point lookups (:meth:`point`,
    :meth:`point_linear`).

    Parameters
    ----------
    tables : np.ndarray
        Flat float32: every material's pair tables, one after the other, each an (n1, P)
        block (:func:`pair_buffers`).
    packed : np.ndarray
        (P,) uint32: their packed atoms.
    header : PairHeader
        Where each material's pairs and rows are.
    rows : np.ndarray
        The shared rows (:attr:`~sparse_brdf.decoders.scene.SharedRows.rows`).
    shape : tuple of int
        The grid (n1, n2, n3).
    grouped : list, optional
        Per material, its :class:`GroupedBlock` (on the grouped decoder) or None.
    """

    def __init__(self, tables, packed, header: PairHeader, rows, shape, grouped=None) -> None:
        mask = (1 << PACK_BITS) - 1
        self.tables = np.asarray(tables, np.float32).ravel()
        self.b = (np.asarray(packed, np.int64) & mask)
        self.c = (np.asarray(packed, np.int64) >> PACK_BITS) & mask
        self.header, self.rows, self.shape = header, np.asarray(rows), tuple(shape)
        self.grouped = [None if g is None else GroupedLookup(g.layout, g.channel)
                        for g in (grouped or [None] * len(header.u))]

    def _channel(self, m: int, ch: int):
        start, n, r2, r3 = (int(v) for v in self.header.u[m, 4 * ch:4 * ch + 4])
        base, total = (int(v) for v in self.header.u[m, 12:14])
        n1 = self.shape[0]
        block = self.tables[base * n1:(base + total) * n1].reshape(n1, total)
        sl = slice(start, start + n)
        return (block[:, start - base:start - base + n].T, r2 + self.b[sl] * self.shape[1],
                r3 + self.c[sl] * self.shape[2])

    def mix(self, m: int) -> np.ndarray:
        """(3, 3) M^T of material ``m``'s colour basis (the identity for "rgb")."""
        return self.header.f[m, 2:11].astype(np.float64).reshape(3, 3)

    def eval(self, m: int, bins) -> np.ndarray:
        """(3, N) transformed R, G, B of material ``m`` at integer bins (i, j, k)."""
        if self.grouped[m] is not None:
            return self.mix(m) @ self.grouped[m].eval(bins)[:, :3].T
        i, j, k = (np.asarray(v, np.int64) for v in bins)
        xs = []
        for ch in range(3):
            t, o2, o3 = self._channel(m, ch)
            prod = (t[:, i].astype(np.float64) * self.rows[o2[:, None] + j]
                    * self.rows[o3[:, None] + k])
            xs.append(prod.sum(axis=0))
        return self.mix(m) @ np.stack(xs)

    def point(self, m: int, i: int, j: int, k: int) -> list:
        """:meth:`eval` at one bin (Python ints): a list of 3 floats."""
        return [float(v) for v in self.eval(m, ([i], [j], [k]))[:, 0]]

    def point_linear(self, m: int, lin) -> list:
        """X of material ``m`` interpolated trilinearly at one point (``lin``: per mode
        (i0, i1, t)): each mode's atoms interpolated linearly, as the kernel does."""
        if self.grouped[m] is not None:
            return (self.mix(m) @ np.array(self.grouped[m].point_linear(lin)[:3])).tolist()
        (i0, i1, ti), (j0, j1, tj), (k0, k1, tk) = ((int(a), int(b), float(t))
                                                     for a, b, t in lin)
        xs = []
        for ch in range(3):
            t, o2, o3 = self._channel(m, ch)
            v1 = (1.0 - ti) * t[:, i0] + ti * t[:, i1]
            v2 = (1.0 - tj) * self.rows[o2 + j0] + tj * self.rows[o2 + j1]
            v3 = (1.0 - tk) * self.rows[o3 + k0] + tk * self.rows[o3 + k1]
            xs.append(float(np.sum(v1 * v2 * v3)))
        return (self.mix(m) @ np.array(xs)).tolist()
