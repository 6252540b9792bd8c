"""The plugin's modules: the package's public names, and the old ``mitsuba_plugin.bsdfs``
path, kept for one release with a DeprecationWarning."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

pytest.importorskip("mitsuba")
pytest.importorskip("drjit")

import mitsuba_plugin  # noqa: E402
from mitsuba_plugin import (  # noqa: E402
    decoders,
    glossy,
    loading,
    neural,
    registration,
    sparse,
    tabulated,
)

#: Where each name the old module held lives now.
MOVED = {
    "register": registration, "classes": registration, "make_classes": registration,
    "variant_kind": registration, "VARIANT_KINDS": registration,
    "srgb_coeff_path": registration, "load_ensemble": loading,
    "GroupedBuffers": decoders, "upload_grouped": decoders, "grouped_x": decoders,
    "StrictBuffers": decoders, "upload_strict": decoders, "strict_x": decoders,
    "GlossyBSDF": glossy, "TabulatedBRDF": tabulated, "SparseBSDF": sparse,
    "NeuralBRDF": neural,
}


def test_package_names():
    assert sorted(mitsuba_plugin.__all__) == sorted(
        ["register", "classes", "make_classes", "PluginError", "DECODERS", "LAYOUTS",
         "LOBES", "SAMPLING", "load_ensemble"])
    for name in mitsuba_plugin.__all__:
        assert getattr(mitsuba_plugin, name) is not None, name
    assert mitsuba_plugin.register is registration.register
    assert mitsuba_plugin.load_ensemble is loading.load_ensemble


def test_importing_the_package_does_not_warn():
    code = ("import sys, mitsuba_plugin; "
            "print('mitsuba_plugin.bsdfs' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code],
                         capture_output=True, text=True, check=True).stdout.strip()
    assert out == "False"


def test_old_module_warns_and_reexports(monkeypatch):
    monkeypatch.delitem(sys.modules, "mitsuba_plugin.bsdfs", raising=False)
    with pytest.warns(DeprecationWarning, match=r"mitsuba_plugin\.bsdfs is deprecated"):
        old = importlib.import_module("mitsuba_plugin.bsdfs")
    for name, module in MOVED.items():
        assert getattr(old, name) is getattr(module, name), name
    for name in ("PluginError", "DECODERS", "LAYOUTS", "SAMPLING"):
        assert getattr(old, name) is getattr(mitsuba_plugin, name), name
    assert set(old.__all__) == set(MOVED) | {"PluginError", "DECODERS", "LAYOUTS", "SAMPLING"}
