"""Material sources: Neural-BRDF files, Mitsuba BSDFs, the corpora and the cache."""

import os
import stat

import numpy as np
import pytest

from sparse_brdf.errors import BRDFFileError
from sparse_brdf.fileio import atomic_write
from sparse_brdf.sources.cache import cache_dir
from sparse_brdf.sources.catalog import mitsuba_catalog
from sparse_brdf.sources.corpora import TEST_FRACTION, get_corpus, list_corpora
from sparse_brdf.sources.load import load_brdf

pytestmark = pytest.mark.numerics

SMALL = (18, 18, 36)


def test_mitsuba_diffuse_is_reflectance_over_pi():
    b = load_brdf({"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.8]}},
                  shape=SMALL)
    v = b.values[b.valid]
    np.testing.assert_allclose(v, np.broadcast_to(np.array([0.2, 0.5, 0.8]) / np.pi, v.shape),
                               rtol=2e-4)
    np.testing.assert_allclose(b.albedo(), [0.2, 0.5, 0.8], rtol=0.03)


def test_mitsuba_conductor_is_glossy_and_reciprocal():
    b = load_brdf("mitsuba:au-ggx-0.08")
    assert b.shape == (90, 90, 180)
    assert b.values[0, 0, 0, 0] > 50 * b.values[60, 10, 90, 0]  # a specular peak
    assert b.values[0, 10, 0, 0] > b.values[0, 10, 0, 2]  # gold: red over blue


def test_builtin_corpus_spans_material_families():
    cat = mitsuba_catalog()
    assert len(cat) >= 40
    kinds = {d["type"] for d in cat.values()}
    assert kinds == {"roughconductor", "roughplastic", "principled", "diffuse"}
    assert any(d.get("sheen", 0) > 0 for d in cat.values())
    assert any(d.get("clearcoat", 0) > 0 for d in cat.values())


def test_builtin_albedo_at_most_one():
    for name in list(mitsuba_catalog())[::6]:
        a = load_brdf(f"mitsuba:{name}").albedo()
        assert np.all(a <= 1.05), (name, a)
        assert np.all(a >= 0)


def test_split_is_deterministic_and_about_15_percent():
    c = get_corpus("mitsuba")
    test = [m.name for m in c.split("test")]
    train = [m.name for m in c.split("train")]
    assert test == [m.name for m in get_corpus("mitsuba").split("test")]
    assert not set(test) & set(train)
    assert len(test) + len(train) == len(c.materials)
    assert abs(len(test) - TEST_FRACTION * len(c.materials)) <= 1
    with pytest.raises(ValueError, match="unknown split"):
        c.split("validation")


def test_cache_is_used_and_survives_corruption():
    src = "mitsuba:cu-ggx-0.12"
    a = load_brdf(src, shape=SMALL)
    files = list(cache_dir().glob("*.npz"))
    assert files
    for f in files:
        f.write_bytes(b"garbage")
    b = load_brdf(src, shape=SMALL)  # corrupt entry recomputed
    np.testing.assert_array_equal(a.values, b.values)


def test_unknown_sources():
    with pytest.raises(KeyError, match="no built-in material"):
        load_brdf("mitsuba:unobtainium")
    with pytest.raises(FileNotFoundError):
        load_brdf("missing.binary")
    with pytest.raises(ValueError, match="unknown corpus"):
        get_corpus("nonexistent-corpus")


def test_unknown_suffix(tmp_path):
    p = tmp_path / "x.txt"
    p.write_text("hi")
    with pytest.raises(BRDFFileError, match="unknown BRDF format"):
        load_brdf(p)


@pytest.mark.shared
def test_spectralon_is_near_one_over_pi(shared_data):
    b = load_brdf(shared_data / "nbrdf" / "rgl" / "spectralon_rgb.h5")
    near_normal = b.values[:40, :40][b.valid[:40, :40]]
    assert np.median(near_normal) == pytest.approx(1 / np.pi, rel=0.1)
    assert np.all(b.albedo() < 1.0) and np.all(b.albedo() > 0.85)


@pytest.mark.shared
def test_shared_corpora_listed(shared_data):
    corpora = list_corpora()
    assert "90" in corpora["merl"] and "46" in corpora["rgl"]
    assert len(get_corpus("merl").split("test")) == round(0.15 * 90)


@pytest.mark.shared
def test_corrupt_nbrdf_file(tmp_path, shared_data):
    p = tmp_path / "broken.h5"
    src = (shared_data / "nbrdf" / "merl" / "gold-paint.h5").read_bytes()
    p.write_bytes(src[: len(src) // 2])
    with pytest.raises(BRDFFileError, match="broken.h5"):
        load_brdf(p)


def test_cache_folder_env(monkeypatch, tmp_path):
    monkeypatch.setenv("SPARSE_BRDF_CACHE", str(tmp_path / "c"))
    assert cache_dir() == tmp_path / "c"
    monkeypatch.delenv("SPARSE_BRDF_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache_dir() == tmp_path / "sparse-brdf"
    assert os.fspath(cache_dir()).endswith("sparse-brdf")


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o002])
def test_atomic_write_gives_a_new_files_mode(tmp_path, umask):
    """An atomically written file has the mode of any newly created file (0o666 & ~umask),
    not mkstemp's 0600, and no temporary file is left beside it."""
    before = os.umask(umask)
    try:
        path = tmp_path / "out.bin"
        with atomic_write(path) as f:
            f.write(b"data")
        plain = tmp_path / "plain.bin"
        plain.write_bytes(b"data")
    finally:
        os.umask(before)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask
    assert stat.S_IMODE(path.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin", "plain.bin"]


def test_failed_atomic_write_leaves_nothing(tmp_path):
    path = tmp_path / "out.txt"
    with pytest.raises(RuntimeError), atomic_write(path, "w") as f:
        f.write("partial")
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
