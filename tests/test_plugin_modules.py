"""The plugin's modules: the package's public names, where each lives, and an import
that warns about nothing."""

from __future__ import annotations

import subprocess
import sys

import pytest

pytest.importorskip("mitsuba")
pytest.importorskip("drjit")

import mitsuba_plugin  # noqa: E402
from mitsuba_plugin import loading, registration  # noqa: E402


def test_package_names():
    assert sorted(mitsuba_plugin.__all__) == sorted(
        ["register", "classes", "make_classes", "PluginError", "DECODERS", "LAYOUTS",
         "LOBES", "load_ensemble", "memory_budget", "resolve", "check_scene"])
    for name in mitsuba_plugin.__all__:
        assert getattr(mitsuba_plugin, name) is not None, name
    assert mitsuba_plugin.register is registration.register
    assert mitsuba_plugin.load_ensemble is loading.load_ensemble


def test_importing_the_package_does_not_warn():
    code = "import mitsuba_plugin, sparse_brdf; print('ok')"
    out = subprocess.run([sys.executable, "-W", "error::DeprecationWarning", "-c", code],
                         capture_output=True, text=True, check=True).stdout.strip()
    assert out == "ok"


def test_the_old_single_module_is_gone():
    with pytest.raises(ImportError):
        __import__("mitsuba_plugin.bsdfs")
