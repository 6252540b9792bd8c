"""The .sbrdf file's colour-basis flag (byte 11): round trips in both bases, files with
flags 0 unchanged, unknown flag bits refused. Version-1 files (exact float32 values);
version 2 (the default) in tests/test_sbrdf_v2.py."""

from __future__ import annotations

import dataclasses
import struct
import zlib

import numpy as np
import pytest

from conftest import SMALL, random_orthonormal
from sparse_brdf.coding.coefficients import SparseBRDF
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.fileformat import (
    FLAG_OPPONENT,
    file_size,
    from_bytes,
    load_sbrdf,
    save_sbrdf,
    to_bytes,
)
from sparse_brdf.errors import BRDFFileError
from sparse_brdf.transforms import colour_matrix, inverse

FLAGS_AT = 11


@pytest.fixture(scope="module")
def ens():
    rng = np.random.default_rng(3)
    us = [np.stack([random_orthonormal(n, rng) for _ in range(2)]) for n in SMALL]
    return Ensemble(*us, taus=np.zeros(2))


def _model(ens, basis: str, counts=(50, 17, 0)) -> SparseBRDF:
    """A random sparse model with unequal counts per channel (one channel empty)."""
    rng = np.random.default_rng(5)
    size = int(np.prod(SMALL))
    locs = [rng.choice(size, n, replace=False) for n in counts]
    vals = [rng.normal(0, 0.3, n).astype(np.float32) for n in counts]
    return SparseBRDF("log-plus-cosine", SMALL, ens.id, [1, 0, 1], locs, vals,
                      name=f"random-{basis}", basis=basis)


@pytest.mark.parametrize("basis", ["rgb", "opponent"])
def test_round_trip_keeps_the_basis(ens, tmp_path, basis):
    m = _model(ens, basis)
    p = save_sbrdf(tmp_path / "m.sbrdf", m, version=1)
    data = p.read_bytes()
    assert len(data) == file_size(67, len(m.name))
    assert data[FLAGS_AT] == (FLAG_OPPONENT if basis == "opponent" else 0)
    r = load_sbrdf(p, ens)
    assert (r.basis, r.transform, r.name) == (basis, m.transform, m.name)
    assert r.n_coeffs.tolist() == [50, 17, 0]
    for c in range(3):
        np.testing.assert_array_equal(r.locations[c], m.locations[c])
        np.testing.assert_array_equal(r.values[c], m.values[c])
    # decoding mixes the coded channels back with M^T before the inverse transform
    want = inverse(np.tensordot(colour_matrix(basis).T, m.coded(ens), axes=1), m.transform)
    got = np.moveaxis(r.decode(ens).values, -1, 0)
    valid = r.decode(ens).valid
    np.testing.assert_allclose(got[:, valid], want[:, valid], rtol=1e-5, atol=1e-6)
    assert to_bytes(r, version=1) == data


def test_rgb_files_are_unchanged(ens):
    """An rgb model's bytes do not depend on the basis field's existence: flags 0, the
    same bytes as the opponent file but for byte 11 and the checksum."""
    rgb = to_bytes(_model(ens, "rgb"), version=1)
    opp = to_bytes(dataclasses.replace(_model(ens, "rgb"), basis="opponent"), version=1)
    assert rgb[FLAGS_AT] == 0 and opp[FLAGS_AT] == FLAG_OPPONENT
    assert rgb[:FLAGS_AT] == opp[:FLAGS_AT]
    assert rgb[FLAGS_AT + 1:-4] == opp[FLAGS_AT + 1:-4]
    assert struct.unpack("<H", rgb[8:10]) == (1,)  # still version 1


@pytest.mark.parametrize("flags", [0x02, 0x80, 0x03])
def test_unknown_flag_bits_are_refused(ens, tmp_path, flags):
    data = bytearray(to_bytes(_model(ens, "opponent")))
    data[FLAGS_AT] = flags
    body = bytes(data[:-4])
    bad = tmp_path / "future.sbrdf"
    bad.write_bytes(body + struct.pack("<I", zlib.crc32(body)))  # a valid checksum
    with pytest.raises(BRDFFileError) as info:
        load_sbrdf(bad)
    msg = str(info.value)
    assert "future.sbrdf" in msg and f"0x{flags:02x}" in msg and "flags" in msg
    assert "\n" not in msg
    with pytest.raises(BRDFFileError, match="<bytes>: unknown flags"):
        from_bytes(bytes(bad.read_bytes()))


def test_flag_is_covered_by_the_checksum(ens, tmp_path):
    data = bytearray(to_bytes(_model(ens, "opponent")))
    data[FLAGS_AT] = 0  # flipped without updating the CRC: corruption, not rgb
    bad = tmp_path / "flipped.sbrdf"
    bad.write_bytes(bytes(data))
    with pytest.raises(BRDFFileError, match="flipped.sbrdf: checksum"):
        load_sbrdf(bad)
