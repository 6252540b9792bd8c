"""Shared fixtures: small grids, a small trained ensemble, shared-data skipping."""

from __future__ import annotations

import numpy as np
import pytest

from sparse_brdf.paths import shared_data_dir

SMALL = (18, 18, 36)
#: A base lobe for test materials in the lobe transforms (alpha, kd and ks per channel,
#: float16 values): a narrow peak on a dim diffuse part, one channel without a peak.
LOBE = (0.0625, 0.125, 0.25, 0.03125, 8.0, 0.0, 2.0)


def pytest_report_header(config) -> list[str]:
    """The kernels this run's numerics use: what differs from one CPU to another
    (docs/testing.md, "Another CPU at home")."""
    import os

    from threadpoolctl import threadpool_info

    blas = sorted({f"{i['internal_api']} {i.get('architecture')}" for i in threadpool_info()
                   if i.get("user_api") == "blas"})
    return [f"numerics: numpy SIMD off {os.environ.get('NPY_DISABLE_CPU_FEATURES') or '-'}; "
            f"BLAS {', '.join(blas)}; Dr.Jit LLVM target "
            f"{os.environ.get('SPARSE_BRDF_LLVM_TARGET') or 'this CPU'}"]


#: The markers of slow work, and what a test that does it without its marker is told.
SLOW_WORK = {"render": "renders with Mitsuba", "train": "trains an ensemble",
             "bench": "runs a bench"}
_running: set[str] | None = None  # the slow work the running test's markers allow; None: any


def pytest_configure(config) -> None:
    """Watch the doors slow work goes through: ``mitsuba.render``, the trainer's
    iteration and the benches' ``run``. A test that passes one without its marker fails,
    so that ``make test-fast`` (``-m "not render and not train and not bench"``) stays
    fast. Work in fixtures and in child processes is not watched."""
    import mitsuba

    from sparse_brdf.benchmark.acquisition_bench import AcquisitionBench
    from sparse_brdf.benchmark.bench import Bench
    from sparse_brdf.training import train

    def guarded(work, fn):
        def run(*args, **kwargs):
            if _running is not None and work not in _running:
                pytest.fail(f"this test {SLOW_WORK[work]}: mark it @pytest.mark.{work}",
                            pytrace=False)
            return fn(*args, **kwargs)
        return run

    mitsuba.render = guarded("render", mitsuba.render)
    train._iterate = guarded("train", train._iterate)
    Bench.run = guarded("bench", Bench.run)
    AcquisitionBench.run = guarded("bench", AcquisitionBench.run)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
    global _running
    _running = {m for m in SLOW_WORK if item.get_closest_marker(m)}
    try:
        yield
    finally:
        _running = None


@pytest.fixture(scope="session", autouse=True)
def _llvm_target():
    """``$SPARSE_BRDF_LLVM_TARGET``: compile every LLVM kernel of the run for that CPU,
    including those of tests that set a variant through Mitsuba directly."""
    import os

    from sparse_brdf.mitsuba_env import LLVM_TARGET_ENV, set_variant

    if os.environ.get(LLVM_TARGET_ENV):
        set_variant("llvm_ad_rgb")


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
