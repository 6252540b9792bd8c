import numpy as np
import pytest

from sparse_brdf.brdf import BRDF
from sparse_brdf.coords import geometric_valid
from sparse_brdf.errors import BRDFFileError, InvalidBRDFError
from sparse_brdf.sources.merl import MERL_SCALE, read_merl, write_merl

SHAPE = (6, 6, 12)


def _brdf(seed=0):
    rng = np.random.default_rng(seed)
    valid = geometric_valid(SHAPE)
    valid[0, 0, 0] = False  # an unmeasured bin
    return BRDF(rng.random((*SHAPE, 3)).astype(np.float32), valid, "rand")


def test_round_trip_exact(tmp_path):
    b = _brdf()
    p = write_merl(tmp_path / "a.binary", b)
    r = read_merl(p)
    assert r.shape == SHAPE
    np.testing.assert_array_equal(r.valid, b.valid)
    np.testing.assert_array_equal(r.values, b.values)
    assert p.stat().st_size == 12 + 3 * np.prod(SHAPE) * 8


def test_channel_scales_and_invalid_marker(tmp_path):
    b = _brdf()
    p = write_merl(tmp_path / "a.binary", b)
    raw = np.fromfile(p, dtype="<f8", offset=12).reshape(3, *SHAPE)
    assert raw[0, 0, 0, 0] == -1.0  # invalid bins written as -1
    i = (3, 2, 5)
    np.testing.assert_allclose(raw[(slice(None), *i)] * MERL_SCALE, b.values[i], rtol=1e-6)


def test_negative_values_read_as_invalid(tmp_path):
    p = write_merl(tmp_path / "a.binary", _brdf())
    raw = bytearray(p.read_bytes())
    off = 12 + 8 * (2 * 72 + 3 * 12 + 4)  # red channel, bin (2, 3, 4)
    raw[off: off + 8] = np.float64(-5.0).tobytes()
    p.write_bytes(bytes(raw))
    r = read_merl(p)
    assert not r.valid[2, 3, 4] and r.values[2, 3, 4].tolist() == [0, 0, 0]


@pytest.mark.parametrize("mangle, match", [
    (lambda b: b[:-8], "truncated"),
    (lambda b: b + b"\0" * 8, "trailing"),
    (lambda b: b[:5], "too short"),
    (lambda b: np.array([90, -1, 180], "<i4").tobytes() + b[12:], "header"),
    (lambda b: np.array([90, 90, 180], "<i4").tobytes() + b[12:], "truncated"),
])
def test_bad_files_name_file_and_problem(tmp_path, mangle, match):
    p = write_merl(tmp_path / "a.binary", _brdf())
    bad = tmp_path / "bad.binary"
    bad.write_bytes(mangle(p.read_bytes()))
    with pytest.raises(BRDFFileError, match=match) as e:
        read_merl(bad)
    assert "bad.binary" in str(e.value)


def test_nan_is_rejected(tmp_path):
    p = write_merl(tmp_path / "a.binary", _brdf())
    raw = bytearray(p.read_bytes())
    raw[12 + 8 * 100: 12 + 8 * 101] = np.float64(np.nan).tobytes()
    p.write_bytes(bytes(raw))
    with pytest.raises(BRDFFileError, match="NaN"):
        read_merl(p)


def test_missing_file():
    with pytest.raises(FileNotFoundError, match="nope.binary"):
        read_merl("nope.binary")


def test_failed_write_leaves_no_partial_file(tmp_path, monkeypatch):
    import sparse_brdf.sources.merl as merl

    target = tmp_path / "a.binary"
    write_merl(target, _brdf(0))
    before = target.read_bytes()

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(merl.np, "ascontiguousarray", boom)
    with pytest.raises(OSError, match="disk full"):
        write_merl(target, _brdf(1))
    monkeypatch.undo()
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["a.binary"]


def test_brdf_rejects_bad_values():
    valid = geometric_valid(SHAPE)
    v = np.ones((*SHAPE, 3), np.float32)
    v[1, 1, 1, 0] = np.inf
    with pytest.raises(InvalidBRDFError, match="NaN or inf"):
        BRDF(v, valid, "x")
    v[1, 1, 1, 0] = -1
    with pytest.raises(InvalidBRDFError, match="negative"):
        BRDF(v, valid, "x")
    with pytest.raises(InvalidBRDFError, match="shape"):
        BRDF(np.ones((4, 4, 3)), valid, "x")
