"""Old module paths keep working for one release: the same module objects, with a
DeprecationWarning on first import (``sparse_brdf/_moved.py``)."""

from __future__ import annotations

import importlib
import subprocess
import sys
import warnings

import pytest

import sparse_brdf
from sparse_brdf._moved import MOVED, MOVED_NAMES, OLD_PACKAGES

# Each test asks for the warning it is about; the old package's own warning comes with it.
pytestmark = pytest.mark.filterwarnings(
    "ignore:sparse_brdf.model is deprecated:DeprecationWarning")


def _fresh(monkeypatch, *names):
    """Forget the old names (and their parents' attributes) so that they import anew."""
    for name in names:
        monkeypatch.delitem(sys.modules, name, raising=False)


def test_every_new_module_of_the_table_exists():
    for new in MOVED.values():
        assert importlib.import_module(new).__name__ == new
        assert new not in MOVED, f"{new} is itself an old path: the table would chain"


@pytest.mark.parametrize("old", sorted(MOVED))
def test_an_old_path_warns_and_gives_the_new_module(old, monkeypatch):
    _fresh(monkeypatch, old, *OLD_PACKAGES)
    with pytest.warns(DeprecationWarning, match=f"{old} is deprecated.*{MOVED[old]}"):
        module = importlib.import_module(old)
    assert module is importlib.import_module(MOVED[old])


def test_from_the_old_package_import_a_name(monkeypatch):
    _fresh(monkeypatch, "sparse_brdf.model", "sparse_brdf.model.encode",
           "sparse_brdf.model.sbrdf")
    with pytest.warns(DeprecationWarning, match="sparse_brdf.model.encode"):
        from sparse_brdf.model import encode as old_encode
    with pytest.warns(DeprecationWarning, match="sparse_brdf.model.sbrdf"):
        from sparse_brdf.model.sbrdf import save_sbrdf
    from sparse_brdf.coding import encode as new_encode
    from sparse_brdf.coding.fileformat import save_sbrdf as new_save

    assert old_encode is new_encode and save_sbrdf is new_save is sparse_brdf.save_sbrdf
    assert old_encode.encode is sparse_brdf.encode


def test_the_old_public_functions_are_the_new_ones(monkeypatch):
    _fresh(monkeypatch, "sparse_brdf.evaluation.acquisition", "sparse_brdf.samples")
    with pytest.warns(DeprecationWarning):
        from sparse_brdf.evaluation.acquisition import encode_samples, pca_from_samples
        from sparse_brdf.samples import Samples
    assert encode_samples is sparse_brdf.encode_samples
    assert pca_from_samples is sparse_brdf.pca_from_samples
    assert Samples is sparse_brdf.Samples


def test_an_old_path_warns_once(monkeypatch):
    _fresh(monkeypatch, "sparse_brdf.model.layouts", *OLD_PACKAGES)
    with pytest.warns(DeprecationWarning):
        import sparse_brdf.model.layouts  # noqa: F401
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        import sparse_brdf.model.layouts as again
    from sparse_brdf.decoders import layouts

    assert again is layouts and layouts.SAMPLING == layouts.LOBES == ("cosine", "lobe")


def test_new_paths_and_the_package_import_without_warnings():
    code = ("import warnings; warnings.simplefilter('error'); import sparse_brdf, "
            "sparse_brdf.coding, sparse_brdf.training, sparse_brdf.acquisition, "
            "sparse_brdf.compared, sparse_brdf.decoders, sparse_brdf.fitting.fit_scene")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]


def _a_moved_name(module, home):
    """A name defined in ``home`` that ``module`` does not hold itself."""
    own = vars(module)
    return next(n for n, v in vars(home).items() if not n.startswith("__") and n not in own
                and getattr(v, "__module__", home.__name__) == home.__name__
                and not isinstance(v, type(sys)))


@pytest.mark.parametrize("name", sorted(MOVED_NAMES))
def test_a_name_that_moved_out_of_a_module_still_imports_from_it(name):
    module = importlib.import_module(name)
    for home_name in MOVED_NAMES[name]:
        home = importlib.import_module(home_name)
        moved = _a_moved_name(module, home)
        with pytest.warns(DeprecationWarning, match=f"{name}.{moved} is deprecated.*{home_name}"):
            assert getattr(module, moved) is getattr(home, moved)
    with pytest.raises(AttributeError, match="no_such_name"):
        module.no_such_name  # noqa: B018


def test_the_command_lines_imports_from_render_still_work():
    with pytest.warns(DeprecationWarning, match="sparse_brdf.evaluation.images.read_exr"):
        from sparse_brdf.evaluation.render import read_exr
    from sparse_brdf.evaluation.images import read_exr as new_read

    assert read_exr is new_read


def test_an_unknown_old_name_is_still_an_import_error():
    with pytest.raises(ImportError):
        importlib.import_module("sparse_brdf.model.no_such_module")
