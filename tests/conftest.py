"""Shared fixtures: small grids, a small trained ensemble, shared-data skipping."""

from __future__ import annotations

import numpy as np
import pytest

from sparse_brdf.paths import shared_data_dir

SMALL = (18, 18, 36)


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory):
    """Keep the tests' tabulation cache out of the user's cache folder."""
    mp = pytest.MonkeyPatch()
    mp.setenv("SPARSE_BRDF_CACHE", str(tmp_path_factory.mktemp("cache")))
    yield
    mp.undo()


@pytest.fixture(scope="session")
def shared_data():
    data = shared_data_dir()
    if data is None:
        pytest.skip("../shared/data is absent: this test needs the shared measured materials")
    return data


@pytest.fixture(scope="session")
def small_training():
    """Transformed channels of 12 built-in materials on the small grid, (72, 18, 18, 36)."""
    from sparse_brdf.sources.corpora import get_corpus
    from sparse_brdf.sources.dataset import training_tensors

    mats = get_corpus("mitsuba").split("train")[::3]
    return training_tensors(mats, shape=SMALL, progress=False)[0]


@pytest.fixture(scope="session")
def small_ensemble(small_training):
    from sparse_brdf.training.train import train_ensemble

    return train_ensemble(small_training, taus=(16, 64), n_dicts=3, n_iter=3, seed=1,
                          progress=False)


def random_orthonormal(n: int, rng: np.random.Generator) -> np.ndarray:
    """A random orthonormal (n, n) matrix whose first column is constant and positive."""
    m = rng.standard_normal((n, n))
    m[:, 0] = 1.0
    q, r = np.linalg.qr(m)
    return (q * np.sign(np.diag(r))).astype(np.float32)


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    """``sparse-brdf ARGV`` in this process: (exit status, stdout, stderr)."""
    from sparse_brdf.cli import main

    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def cli_fails(capsys, *argv, names=()) -> str:
    """Run ARGV, assert status 2 and one stderr line naming each of ``names``; the line."""
    code, _, err = run_cli(capsys, *argv)
    lines = err.splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for name in names:
        assert str(name) in lines[0], (name, lines[0])
    return lines[0]
