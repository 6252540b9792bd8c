"""The flat buffers a renderer reads for a sparse BRDF, their byte counts, and numpy
reference decoders for testing without a renderer.

Everything here is plain numpy, prepared at scene-load time: the ``sparse_brdf`` Mitsuba
plugin (:mod:`mitsuba_plugin.sparse`) uploads these arrays to Dr.Jit as they are
(:func:`grouped_layout`, :func:`strict_layout`,
:func:`~sparse_brdf.decoders.buffers.float_buffer`), their byte counts are known without
a renderer (:func:`grouped_bytes`, ``StrictChannel.nbytes``), and
numpy evaluators (``grouped_eval`` below; the uploaded layouts' lookups, vectorised
and one point at a time, in :mod:`sparse_brdf.decoders.lookups`) mirror its Dr.Jit
kernels so the decoders can be checked without Mitsuba. The decoder, layout and
sampling names the plugin accepts are defined here (:data:`DECODERS`, :data:`LAYOUTS`,
:data:`LOBES`: the importance-sampling strategies; the lobe itself is fitted in
:mod:`~sparse_brdf.decoders.lobe`).

Sparse model of one channel (Tongbuasirilai et al., "A Sparse Non-parametric BRDF
Model", and docs/method.md)::

    X[i, j, k] = sum_t s_t U1[i, a_t] U2[j, b_t] U3[k, c_t]
    rho        = max((exp(X) - 1) / w, 0)

with w the transform's weight (``transforms.weight``): 1 (log-plus), clip(cos_i cos_o,
0.01, 1) at the bin's lower-edge angles (log-plus-cosine), or either times the relative
transforms' scale s. Neither decoder ever builds the (n1, n2, n3) tensor:

- **grouped**: the terms are grouped by the atom of one mode ``g`` (the same mode for the
  three channels: the fewest packets read per lookup, see below). The two other modes
  ``p < q`` are contracted at load time into
  ``table[ip * nq + iq, G] = sum_{t in G} s_t Up[ip, p_t] Uq[iq, q_t]``
  (shape (np * nq, K), K = distinct atoms of mode g), and the K atom
  columns of mode g are kept as rows ``V[G, :]``. A lookup is
  ``X = sum_G table[(ip, iq), G] * V[G, ig]``: K fused multiply-adds. As uploaded
  (:func:`grouped_layout`), the three channels share one row per bin pair and one row
  of atom values per bin of mode g, both read with packet loads, and the same rows carry
  the two separable factors of the bin's ``cos_i cos_o`` (:func:`weight_factors`: weight
  and validity without any trigonometry). Two layouts, whichever reads fewer packets:
  "union" stores each distinct atom of the three channels once (channels usually share
  their dictionary and most atoms), "slots" gives every channel its own atom columns.
- **strict**: keeps the nonzero terms (s_t and the packed indices of its three atoms
  among the distinct atoms of each mode) and the distinct atom columns of each mode.
  The terms are sorted by (c, b, a), and a lookup runs one loop over them evaluating
  ``sum_c U3[k, c] sum_b U2[j, b] sum_a s U1[i, a]``: partial sums are closed at the
  end of each b-group and c-group (flag bits of the packed indices, the same for every
  lane), so U2 and U3 are read once per group rather than once per term. Least memory,
  slowest.

Colour basis: the three channels are the model's *coded* channels. In the "rgb" basis they
are the transformed R, G, B; in the "opponent" basis (``SparseBRDF.basis``) a lookup mixes
the three coded values X_0, X_1, X_2 back into the transformed R, G, B with the constant
3 x 3 matrix M^T (:func:`~.buffers.colour_mix`, 9 multiply-adds, fewer for its zero entries) before
the inverse transform; a channel may hold no terms (its X is 0).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from ..coords import bin_angles
from ..params import check_choice

#: The ``sparse_brdf`` plugin's decoders ("auto": :func:`choose_decoder` picks one).
DECODERS = ("grouped", "strict", "auto")

#: The grouped decoder's row layouts ("auto": :func:`layout_kind` picks one).
LAYOUTS = ("auto", "union", "slots")

#: Both plugins' importance-sampling lobes (their ``sampling`` parameter): the
#: cosine-weighted hemisphere, or that mixed with the glossy lobe of :func:`.lobe.fit_lobe`.
LOBES = ("cosine", "lobe")

#: The plugins' defaults of those choices (``sparse-brdf render`` takes them too). Lobe
#: sampling is the lower-noise choice for a user's image; comparisons of renders set
#: ``cosine`` (:data:`sparse_brdf.evaluation.render.SHARED_PATHS`), which gives every
#: material the same sample paths for one seed and spp.
PLUGIN_DEFAULTS = {"decoder": "auto", "layout": "auto", "sampling": "lobe"}

#: ``decoder="auto"`` uses "grouped" unless its tables would take more than this many
#: bytes (all three channels), then "strict". The grouped decoder is many times faster
#: (measured on the sphere scene, docs/benchmarks.md: 1.0-1.14x the dense table's render
#: time at 32-262 coefficients per channel, the strict decoder 3-19x), so it is kept up
#: to twice the dense float32 table of a MERL BRDF (90 * 90 * 180 * 3 * 4 bytes =
#: 16.7 MiB). Measured on MERL blue-metallic-paint2 with the shipped ensemble: 32, 128
#: and 262 coefficients per channel need 0.53, 0.79 and 1.05 MB.
AUTO_GROUPED_MAX_BYTES = 32 * 1024 * 1024

#: Bits per atom index in the strict decoder's packed term indices (3 x 10 bits), then
#: bit 30: last term of its (c, b) group, bit 31: last term of its c group.
PACK_BITS = 10

#: Floats per packet gather: the grouped decoder reads table rows and atom values in
#: contiguous runs of this many floats (Dr.Jit turns these into packet loads instead of
#: per-lane gathers, see ``drjit.JitFlag.PacketOps``).
PACKET = 8

#: Floats per slot of the grouped layout: channels 0, 1, 2 and the bin weight.
SLOT = 4

#: Atoms per chunk of the union layout (:func:`union_layout`): 5 atoms x 3 channels +
#: one weight factor fill two packets of table row, 5 atom values + one weight factor
#: one packet of atom values.
UNION_ATOMS = 5
assert (3 * UNION_ATOMS + 1) == 2 * PACKET

#: Products in the bin weight's separable form (:func:`weight_factors`).
WEIGHT_RANK = 2
END_B = 1 << 30
END_C = 1 << 31


@dataclass
class GroupedChannel:
    """The grouped decoder's data of one colour channel (see module docstring)."""

    mode_p: int  # first contracted mode
    mode_q: int  # second contracted mode
    mode_g: int  # grouped mode
    n_q: int  # size of mode q (the table's row stride)
    table: np.ndarray  # (n_p * n_q, K) float32, row-major
    rows: np.ndarray  # (K, n_g) float32: the K distinct atom columns of mode g
    atoms: np.ndarray | None = None  # (K,) their indices in the dictionary
    source: int = 0  # the dictionary (index in the ensemble)

    @property
    def k(self) -> int:
        return int(self.rows.shape[0])

    @property
    def nbytes(self) -> int:
        return int(self.table.nbytes + self.rows.nbytes)


@dataclass
class StrictChannel:
    """The strict decoder's data of one colour channel."""

    values: np.ndarray  # (T,) float32
    packed: np.ndarray  # (T,) uint32: ia | ib << 10 | ic << 20 | END_B | END_C
    rows: tuple[np.ndarray, np.ndarray, np.ndarray]  # (K_n, n_n) distinct atom columns

    @property
    def n_terms(self) -> int:
        return int(self.values.size)

    @property
    def nbytes(self) -> int:
        return int(self.values.nbytes + self.packed.nbytes + sum(r.nbytes for r in self.rows))


def channel_terms(model, ensemble, c: int):
    """(s, (a, b, k), (U1, U2, U3)) of channel ``c`` of a SparseBRDF."""
    us = ensemble.dictionary(int(model.dict_index[c]))
    modes = tuple(np.asarray(m, np.int64) for m in model.modes(c))
    return np.asarray(model.values[c], np.float32), modes, us


def _grouped_mode(modes, shape) -> int:
    """The mode with the fewest distinct atoms (ties: the smaller table)."""
    def cost(g):
        p, q = (m for m in range(3) if m != g)
        k = np.unique(modes[g]).size
        return (k, shape[p] * shape[q] * k + k * shape[g])

    return min(range(3), key=cost)


def grouped_channel(s, modes, us, mode_g: int | None = None,
                    source: int = 0) -> GroupedChannel:
    """Build the grouped table of one channel (optionally forcing the grouped mode);
    ``source`` is the channel's dictionary index, kept to find atoms channels share."""
    shape = tuple(u.shape[0] for u in us)
    if mode_g is None:
        mode_g = _grouped_mode(modes, shape)
    p, q = (m for m in range(3) if m != mode_g)
    atoms, group = np.unique(modes[mode_g], return_inverse=True)
    k = atoms.size
    table = np.zeros((shape[p] * shape[q], max(k, 1)), np.float64)
    up, uq = us[p].astype(np.float64), us[q].astype(np.float64)
    for g in range(k):
        sel = group == g
        # sum_t s_t Up[:, p_t] Uq[:, q_t]^T, an (n_p, n_q) matrix
        m = (up[:, modes[p][sel]] * s[sel].astype(np.float64)) @ uq[:, modes[q][sel]].T
        table[:, g] = m.ravel()
    rows = us[mode_g][:, atoms].T.astype(np.float32) if k else np.zeros((1, shape[mode_g]),
                                                                        np.float32)
    return GroupedChannel(p, q, mode_g, shape[q], np.ascontiguousarray(table, np.float32),
                          np.ascontiguousarray(rows), atoms.astype(np.int64), int(source))


def strict_channel(s, modes, us) -> StrictChannel:
    """Build the strict decoder's data of one channel."""
    idx, rows = [], []
    for m in range(3):
        atoms, inv = np.unique(modes[m], return_inverse=True)
        if atoms.size >= 1 << PACK_BITS:
            raise ValueError(f"mode {m + 1} has {atoms.size} distinct atoms; the strict "
                             f"decoder packs at most {(1 << PACK_BITS) - 1}")
        idx.append(inv.astype(np.uint32))
        r = us[m][:, atoms].T if atoms.size else np.zeros((1, us[m].shape[0]))
        rows.append(np.ascontiguousarray(r, np.float32))
    order = np.lexsort((idx[0], idx[1], idx[2]))  # by c, then b, then a
    ia, ib, ic = (x[order] for x in idx)
    last = np.arange(ia.size) == ia.size - 1
    end_c = last | np.append(ic[1:] != ic[:-1], True)
    end_b = end_c | np.append(ib[1:] != ib[:-1], True)
    packed = (ia | (ib << PACK_BITS) | (ic << (2 * PACK_BITS))).astype(np.uint64)
    packed |= np.where(end_b, END_B, 0).astype(np.uint64)
    packed |= np.where(end_c, END_C, 0).astype(np.uint64)
    values = np.asarray(s, np.float32)[order]
    return StrictChannel(values, packed.astype(np.uint32), tuple(rows))


@dataclass
class StrictLayout:
    """The three channels' strict data as uploaded (:func:`strict_layout`): each array
    holds channel 0's data, then channel 1's, then channel 2's."""

    values: np.ndarray  # float32: the terms' coefficients
    packed: np.ndarray  # uint32: their packed atom indices and group-end flags
    rows: np.ndarray  # flat float32: per channel, its distinct atom rows of modes 1, 2, 3
    n_terms: tuple[int, ...]  # per channel: its number of terms
    term_offsets: tuple[int, ...]  # per channel: index of its first term
    row_offsets: tuple[tuple[int, int, int], ...]  # per channel and mode: first float


def strict_layout(chans) -> StrictLayout:
    """The :class:`StrictChannel` data of the three channels, concatenated."""
    soff = np.cumsum([0] + [ch.n_terms for ch in chans])
    rows = [r for ch in chans for r in ch.rows]
    roff = np.cumsum([0] + [r.size for r in rows])
    return StrictLayout(
        np.concatenate([ch.values for ch in chans]),
        np.concatenate([ch.packed for ch in chans]),
        np.concatenate([r.ravel() for r in rows]),
        tuple(ch.n_terms for ch in chans),
        tuple(int(soff[c]) for c in range(len(chans))),
        tuple(tuple(int(roff[3 * c + mode]) for mode in range(3)) for c in range(len(chans))))


def atom_keys(model, ensemble, g: int) -> list[set]:
    """Per channel of ``model``, its distinct atoms of mode ``g`` as (dictionary, atom)."""
    out = []
    for c in range(3):
        d = int(model.dict_index[c])
        out.append({(d, int(a)) for a in np.unique(channel_terms(model, ensemble, c)[1][g])})
    return out


@dataclass(frozen=True)
class GroupedPlan:
    """The grouped decoder's shape for one material, decided once without building its
    tables (:func:`grouped_plan`): every use of the grouped mode reads it from here.

    Attributes
    ----------
    mode : int
        The grouped mode g (0, 1 or 2), the same for the three channels.
    kind : str
        The layout that reads fewer packets per lookup, "union" or "slots"
        (:func:`layout_for`).
    chunks : int
        Loop iterations per lookup in that layout.
    nbytes : int
        Bytes of that layout's tables and atom values.
    """

    mode: int
    kind: str
    chunks: int
    nbytes: int

    @property
    def packets(self) -> int:
        """Packets of ``PACKET`` floats one lookup reads (:func:`layout_packets`)."""
        return layout_packets(self.kind, self.chunks)


def grouped_plan(model, ensemble) -> GroupedPlan:
    """The :class:`GroupedPlan` of ``model``: the grouped mode for all three channels is
    the one that reads the fewest packets per lookup (:func:`layout_packets`), ties
    broken by the smaller tables. One mode for the three channels lets them share one
    row per bin pair."""
    shape = tuple(model.shape)
    plans = []
    for g in range(3):
        kind, chunks = layout_for(atom_keys(model, ensemble, g))
        plans.append(GroupedPlan(g, kind, chunks, _layout_bytes(kind, chunks, shape, g)))
    return min(plans, key=lambda p: (p.packets, p.nbytes))


def grouped_channels(model, ensemble, mode: int | None = None) -> list[GroupedChannel]:
    """The grouped data of the three channels, all grouped on mode ``mode`` (None: the
    mode of :func:`grouped_plan`; give it when the plan is already at hand)."""
    g = grouped_plan(model, ensemble).mode if mode is None else int(mode)
    return [grouped_channel(*channel_terms(model, ensemble, c), mode_g=g,
                            source=int(model.dict_index[c])) for c in range(3)]


def n_slots(ks) -> int:
    """Slots of the slot layout: the largest of the channels' K (at least the weight's
    two), rounded up to whole packets (``PACKET // SLOT`` slots)."""
    per = PACKET // SLOT
    need = max([WEIGHT_RANK] + [int(k) for k in ks])
    return per * -(-need // per)


def union_chunks(k_union: int) -> int:
    """Chunks of the union layout for ``k_union`` distinct atoms over the three channels
    (at least the weight's two)."""
    return max(WEIGHT_RANK, -(-int(k_union) // UNION_ATOMS))


#: Packets a lookup reads per loop iteration: (table, atom values).
_PACKETS_PER_CHUNK = {"slots": (1, 1), "union": (2, 1)}


def layout_packets(kind: str, chunks: int) -> int:
    """Packets of ``PACKET`` floats one lookup reads in ``kind`` with ``chunks`` chunks."""
    return chunks * sum(_PACKETS_PER_CHUNK[kind])


def layout_kind(ks, k_union: int) -> tuple[str, int]:
    """(layout, chunks) that reads fewer packets per lookup, for channels with ``ks``
    distinct atoms of the grouped mode and ``k_union`` over the three (ties: slots)."""
    slots = n_slots(ks) * SLOT // PACKET
    union = union_chunks(k_union)
    if layout_packets("union", union) < layout_packets("slots", slots):
        return "union", union
    return "slots", slots


def layout_for(keys: list[set]) -> tuple[str, int]:
    """:func:`layout_kind` for channels whose distinct atoms of the grouped mode are the
    (dictionary, atom) sets ``keys``."""
    return layout_kind([len(k) for k in keys], len(set().union(*keys)))


def _layout_bytes(kind: str, chunks: int, shape, g: int) -> int:
    """Bytes of a layout's tables and atom values on grid ``shape``, grouped mode g."""
    n_pq = int(np.prod([n for m, n in enumerate(shape) if m != g]))
    t, v = _PACKETS_PER_CHUNK[kind]
    return int((n_pq * t + shape[g] * v) * chunks * PACKET * 4)


def weight_factors(shape, mode_g: int) -> tuple[np.ndarray, np.ndarray]:
    """Rank-2 factors of the bins' ``cos_i cos_o`` for the grouped layout.

    At the lower-edge angles of bin (i, j, k) (docs/method.md, "Grid, lookup convention,
    validity"), ``cos_i cos_o = cos_d^2 cos_h^2 - sin_d^2 sin_h^2 cos_p^2``, a sum of two
    products separable into the contracted pair (p, q) and the grouped mode g. Returns
    (pair, atom): shapes (n_p * n_q, 2) and (n_g, 2), float64, with ``cos_i cos_o =
    pair[(ip, iq)] . atom[ig]``.
    """
    th, td, pd = bin_angles(tuple(shape))
    # per mode: its factor in the first product and in the second
    first = (np.cos(th) ** 2, np.cos(td) ** 2, np.ones_like(pd))
    second = (np.sin(th) ** 2, np.sin(td) ** 2, np.cos(pd) ** 2)
    p, q = (m for m in range(3) if m != mode_g)
    pair = np.stack([np.outer(first[p], first[q]).ravel(),
                     np.outer(second[p], second[q]).ravel()], axis=1)
    atom = np.stack([first[mode_g], -second[mode_g]], axis=1)  # the second is subtracted
    return pair, atom


@dataclass
class GroupedLayout:
    """The three channels' grouped data as uploaded (:func:`grouped_layout`)."""

    kind: str  # "slots" or "union"
    tables: np.ndarray  # flat float32: per bin pair, ``chunks`` chunks of table floats
    values: np.ndarray  # flat float32: per bin of mode g, ``chunks`` chunks of atom values
    chunks: int  # loop iterations per lookup

    @property
    def packets(self) -> int:
        return layout_packets(self.kind, self.chunks)


def _check_modes(chans) -> None:
    if len({(ch.mode_p, ch.mode_q, ch.mode_g) for ch in chans}) != 1:
        raise ValueError("the shared grouped layout needs one grouped mode for all channels")


def slot_layout(chans, shape) -> GroupedLayout:
    """Slots of ``SLOT`` = 4 floats: in slot s of the row of bin pair (ip, iq), column s
    of the tables of channels 0, 1, 2 (0 past a channel's K) and column s of the bin
    weight's pair factors (:func:`weight_factors`; 0 past its two); the atom values at
    one bin of mode g are laid out the same way. A chunk is one packet of each (two
    slots); the kernel keeps one multiply-add sum per float of the packet, float 4 s + c
    adding to channel c (c = 3: the bin's ``cos_i cos_o``), so it needs no selects.
    Arrays (n_p * n_q, slots, 4) and (n_g, slots, 4), flattened."""
    _check_modes(chans)
    slots = n_slots([ch.k for ch in chans])
    pair, atom = weight_factors(shape, chans[0].mode_g)
    tab = np.zeros((chans[0].table.shape[0], slots, SLOT), np.float32)
    vals = np.zeros((chans[0].rows.shape[1], slots, SLOT), np.float32)
    for c, ch in enumerate(chans):
        tab[:, :ch.k, c] = ch.table[:, :ch.k]
        vals[:, :ch.k, c] = ch.rows[:ch.k].T
    tab[:, :WEIGHT_RANK, 3] = pair
    vals[:, :WEIGHT_RANK, 3] = atom
    return GroupedLayout("slots", tab.ravel(), vals.ravel(), slots * SLOT // PACKET)


def union_layout(chans, shape) -> GroupedLayout:
    """Each distinct (dictionary, atom) of the three channels once: atom u sits in chunk
    u // 5 at position a = u % 5. A chunk of the row of bin pair (ip, iq) is 16 floats:
    float 3 a + c is channel c's table column of that atom (0 if the channel does not
    use it), float 15 the bin weight's pair factor r = chunk (chunks 0 and 1); a chunk of
    atom values is 8 floats: the 5 atoms' values at the bin of mode g, the weight's atom
    factor (float 5), two zeros. Arrays (n_p * n_q, chunks, 16) and (n_g, chunks, 8),
    flattened."""
    _check_modes(chans)
    keys: dict[tuple[int, int], int] = {}
    for ch in chans:
        for a in ch.atoms:
            keys.setdefault((ch.source, int(a)), len(keys))
    chunks = union_chunks(len(keys))
    width = UNION_ATOMS * 3 + 1  # two packets
    tab = np.zeros((chans[0].table.shape[0], chunks, width), np.float32)
    vals = np.zeros((chans[0].rows.shape[1], chunks, PACKET), np.float32)
    for c, ch in enumerate(chans):
        for col, a in enumerate(ch.atoms):
            u = keys[(ch.source, int(a))]
            tab[:, u // UNION_ATOMS, 3 * (u % UNION_ATOMS) + c] = ch.table[:, col]
            vals[:, u // UNION_ATOMS, u % UNION_ATOMS] = ch.rows[col]
    pair, atom = weight_factors(shape, chans[0].mode_g)
    tab[:, :WEIGHT_RANK, width - 1] = pair
    vals[:, :WEIGHT_RANK, UNION_ATOMS] = atom
    return GroupedLayout("union", tab.ravel(), vals.ravel(), chunks)


def grouped_layout(chans, shape, kind: str | None = None) -> GroupedLayout:
    """The three channels' grouped data as uploaded: the layout of :func:`layout_kind`
    (fewer packets per lookup) unless ``kind`` ("slots" or "union") forces one."""
    _check_modes(chans)
    if kind is None:
        kind, _ = layout_for([{(ch.source, int(a)) for a in ch.atoms} for ch in chans])
    if check_choice("grouped layout", kind, LAYOUTS[1:]) == "slots":  # "union", "slots"
        return slot_layout(chans, shape)
    return union_layout(chans, shape)


def grouped_bytes(model, ensemble) -> int:
    """Bytes the grouped decoder holds for ``model`` (the layout of
    :func:`grouped_layout`), without building the tables."""
    return grouped_plan(model, ensemble).nbytes


def choose_decoder(decoder: str, model, ensemble,
                   max_bytes: int = AUTO_GROUPED_MAX_BYTES,
                   plan: GroupedPlan | None = None) -> str:
    """Resolve ``"auto"`` to "grouped" or "strict"; check the name. ``plan``: the
    model's :class:`GroupedPlan` if already at hand (None: made here, for "auto" only)."""
    if check_choice("decoder", decoder, DECODERS) != "auto":
        return decoder
    if plan is None:
        plan = grouped_plan(model, ensemble)
    return "grouped" if plan.nbytes <= max_bytes else "strict"


# ----------------------------------------------------------------------- numpy mirrors


def grouped_eval(ch: GroupedChannel, bins) -> np.ndarray:
    """X at integer bins (i, j, k) from a grouped channel (numpy mirror of the kernel)."""
    pair = bins[ch.mode_p] * ch.n_q + bins[ch.mode_q]
    return np.einsum("ng,gn->n", ch.table[pair], ch.rows[:, bins[ch.mode_g]])


def strict_orders(model, ensemble) -> list[np.ndarray]:
    """The order in which the strict decoder holds each channel's terms.

    Read off :func:`strict_channel` built with the values 0, 1, 2, ..., so that the
    order stays defined in one place. The plugin's derivative carrier uses it to gather
    each term's differentiable value inside the kernel.

    Parameters
    ----------
    model : SparseBRDF
        The encoded material.
    ensemble : Ensemble
        Its ensemble.

    Returns
    -------
    list of 3 ndarray, int64, shapes (n_terms[c],)
        Term ``i`` of the strict decoder's channel ``c`` is the file's term ``order[c][i]``.
    """
    out = []
    for c in range(3):
        s, modes, us = channel_terms(model, ensemble, c)
        probe = np.arange(s.size, dtype=np.float32)
        out.append(strict_channel(probe, modes, us).values.astype(np.int64))
    return out


def model_digest(model) -> bytes:
    """A digest of everything a decoder's buffers are built from: the model's shape,
    transform, colour basis, dictionaries, atoms and values (the plugin keys its last
    grouped build by it, with the ensemble, layout and variant)."""
    h = hashlib.sha256(repr((tuple(model.shape), model.transform, model.basis)).encode())
    h.update(np.ascontiguousarray(model.dict_index, np.int64).tobytes())
    for a in (*model.locations, *model.values):
        a = np.asarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.digest()


def term_values(arrays, n_terms) -> list[np.ndarray]:
    """The coded channels' coefficient values, checked, as flat float32 arrays.

    Parameters
    ----------
    arrays : sequence of 3 array-likes
        One per coded channel: numpy arrays or Dr.Jit arrays (read through the buffer
        protocol), in the file's term order.
    n_terms : sequence of 3 int
        The number of terms each channel's fixed support holds.

    Returns
    -------
    list of 3 ndarray, float32, shapes (n_terms[c],)

    Raises
    ------
    ValueError
        A channel holds another number of values than its support, or NaN or inf.
    """
    out = []
    for c, (v, n) in enumerate(zip(arrays, n_terms, strict=True)):
        a = np.asarray(v, np.float32).ravel()
        if a.size != n:
            raise ValueError(f"values_{c} holds {a.size} values, channel {c} has {n} terms "
                             "(the support is fixed)")
        if not np.isfinite(a).all():
            raise ValueError(f"values_{c} holds NaN or inf values")
        out.append(a)
    return out

