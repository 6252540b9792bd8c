"""Loading a ``sparse_brdf`` material resolves each input once: one grouped plan (the
grouped mode, layout and bytes), one check of the file against its ensemble, one
resolution of each path. The counts come from counters patched in where the code looks
each function up, as ``tests/test_encode_spec.py`` does for encoding."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from conftest import SMALL, random_orthonormal
from sparse_brdf.coding.coefficients import SparseBRDF
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.fileformat import save_sbrdf
from sparse_brdf.decoders import layouts, scene
from sparse_brdf.evaluation.scenes import cause_message, scene_xml
from sparse_brdf.paths import SCENES_DIR

mi = pytest.importorskip("mitsuba")

from test_plugin import make_exact_material, use_variant  # noqa: E402

from mitsuba_plugin import budget, sparse_buffers  # noqa: E402


@pytest.fixture(scope="module")
def material(tmp_path_factory):
    return make_exact_material(tmp_path_factory.mktemp("loading"), n_coeffs=60)


@pytest.fixture(params=["scalar_rgb", "llvm_ad_rgb"])
def variant(request):
    return use_variant(request.param)


def _counting(monkeypatch, calls: dict, name: str, modules) -> None:
    """Count the calls of ``name`` through each module of ``modules`` that holds it."""
    real = getattr(modules[0], name)

    def counted(*args, **kwargs):
        calls[name] = calls.get(name, 0) + 1
        return real(*args, **kwargs)

    for m in modules:
        monkeypatch.setattr(m, name, counted)


@pytest.mark.parametrize("decoder", ["auto", "grouped", "strict"])
def test01_one_grouped_plan_and_one_ensemble_check(material, variant, decoder, monkeypatch):
    calls: dict = {}
    _counting(monkeypatch, calls, "grouped_plan", [layouts, scene, sparse_buffers])
    _counting(monkeypatch, calls, "check_ensemble", [SparseBRDF])
    sparse_buffers.LAST_GROUPED[:] = [None, None]  # no reuse of an earlier test's tables
    b = mi.load_dict({"type": "sparse_brdf", "filename": material["sbrdf"],
                      "ensemble": material["ensemble"], "decoder": decoder})
    budget.resolve(b)  # an auto material: its decoder decided and built
    assert b.decoder in ("grouped", "strict")
    # the budget weighs the plan and the grouped build reads it: made once, or never
    # for a strict material that was not left to the budget
    assert calls.get("grouped_plan", 0) == (0 if decoder == "strict" else 1)
    assert calls["check_ensemble"] == 1


def test02_a_grid_other_than_the_ensembles_fails_in_one_line(material, tmp_path, variant):
    rng = np.random.default_rng(0)
    tiny = Ensemble(*(random_orthonormal(n, rng)[None] for n in (6, 5, 10)), taus=np.zeros(1))
    ens = tiny.save(tmp_path / "tiny.npz")
    model = SparseBRDF("log-plus", SMALL, tiny.id, [0, 0, 0], [[0], [0], [0]],
                       [[1.0], [1.0], [1.0]], name="g")
    path = save_sbrdf(tmp_path / "grid.sbrdf", model)
    with pytest.raises(Exception) as info:  # noqa: PT011 - Mitsuba re-raises it
        mi.load_dict({"type": "sparse_brdf", "filename": str(path), "ensemble": str(ens)})
    assert "PluginError" in str(info.value)
    message = cause_message(info.value)  # the line a command prints
    assert "\n" not in message
    assert message.endswith(f"sparse_brdf: cannot load {str(path)!r}: g: grid 18x18x36, "
                            "but its ensemble's is 6x5x10"), message


def test03_each_path_is_resolved_once(material, tmp_path, monkeypatch, variant):
    """``scene_xml`` makes a material's path absolute (from the current folder); the
    plugin takes it as given and asks Mitsuba's resolver only for relative names."""
    sbrdf = Path(material["sbrdf"])
    monkeypatch.chdir(sbrdf.parent)
    xml = scene_xml(SCENES_DIR / "sphere.xml", {"material": sbrdf.name},
                    sparse_options={"ensemble": Path(material["ensemble"]).name})
    props = {e.get("name"): e.get("value") for e in ET.fromstring(xml).iter("string")
             if e.get("name") in ("filename", "ensemble")}
    assert props == {"filename": str(sbrdf.resolve()),
                     "ensemble": str(Path(material["ensemble"]).resolve())}
    calls: dict = {}
    _counting(monkeypatch, calls, "file_resolver", [mi])
    mi.load_dict({"type": "sparse_brdf", **props})
    assert calls == {}  # absolute names: resolved once, by scene_xml
    mi.load_dict({"type": "sparse_brdf", "filename": sbrdf.name,
                  "ensemble": Path(material["ensemble"]).name})
    assert calls == {"file_resolver": 2}  # relative names: one resolution each
