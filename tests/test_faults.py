"""Faults in distributed and long runs: a Dask worker killed in the middle of a batch
encode, a bench and a training iteration; a training run killed with SIGKILL and resumed
from its checkpoint; two processes writing one batch output folder at once.

Each run must end as an undisturbed run does (the same bytes, the same ensemble id), or
stop with one line and finish on the next run from where it stopped.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.batch import encode_batch
from sparse_brdf.benchmark.bench import Bench
from sparse_brdf.benchmark.bench_config import BenchConfig
from sparse_brdf.cli import main
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.fileformat import load_sbrdf
from sparse_brdf.parallel import start_executor
from sparse_brdf.sources.load import load_brdf
from sparse_brdf.sources.merl import write_merl

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "sparse_brdf.cli"]
MATERIALS = ("au-ggx-0.08", "plastic-red-ggx-0.05", "cu-ggx-0.35", "diffuse-grey",
             "al-ggx-0.06", "plastic-blue-ggx-0.2", "principled-sheen-red-0.9",
             "ag-ggx-0.4")


@pytest.fixture(scope="module")
def cluster():
    """A local cluster of 2 worker processes of this module's own (its workers get killed)."""
    pytest.importorskip("dask.distributed")
    ex = start_executor(workers=2)
    try:
        yield ex
    finally:
        ex.close()


class WorkerKiller:
    """SIGKILL one worker of ``ex`` as soon as the scheduler has a task whose key starts
    with one of ``prefixes`` processing there (a thread; ``killed``: that worker's
    address, None if no such task was seen). The nanny then starts a new worker."""

    def __init__(self, ex, *prefixes: str, when: Path | None = None, timeout: float = 120.0):
        self.client, self.prefixes, self.killed = ex.client, prefixes, None
        self.when = when  # if given: only once this file exists
        self.client.wait_for_workers(2, timeout=60)
        self.pids = self.client.run(os.getpid)
        self._stop = threading.Event()
        self._deadline = time.monotonic() + timeout
        self._thread = threading.Thread(target=self._watch, daemon=True)
        self._thread.start()

    def _watch(self) -> None:
        while not self._stop.is_set() and time.monotonic() < self._deadline:
            if self.when is not None and not self.when.exists():
                time.sleep(0.005)
                continue
            for addr, keys in self.client.processing().items():
                if addr in self.pids and any(str(k).startswith(self.prefixes) for k in keys):
                    os.kill(self.pids[addr], signal.SIGKILL)
                    self.killed = addr
                    return
            time.sleep(0.005)

    def __enter__(self) -> WorkerKiller:
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


@pytest.fixture(scope="module")
def materials(tmp_path_factory):
    folder = tmp_path_factory.mktemp("materials")
    for name in MATERIALS:
        write_merl(folder / f"{name}.binary", load_brdf(f"mitsuba:{name}", shape=SMALL))
    return folder


@pytest.fixture(scope="module")
def ensemble_file(small_ensemble, tmp_path_factory):
    path = tmp_path_factory.mktemp("ens") / "small.npz"
    small_ensemble.save(path)
    return path


def _outputs(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())
            if p.suffix == ".sbrdf"}


def _leftovers(folder: Path) -> list[str]:
    """Temporary files of atomic writes left in ``folder`` (there must be none)."""
    return sorted(p.name for p in folder.rglob("*") if p.name.endswith(".tmp"))


# ------------------------------------------------------------------ a Dask worker dies


def test_batch_encode_survives_a_killed_worker(materials, small_ensemble, cluster, tmp_path):
    opts = {"n_coeffs": 24}
    here = encode_batch(materials, tmp_path / "here", small_ensemble, opts, progress=False)
    with WorkerKiller(cluster, "encode_material") as killer:
        there = encode_batch(materials, tmp_path / "there", small_ensemble, opts, cluster,
                             progress=False)
    assert killer.killed is not None, "no worker was killed: the test did not test"
    assert there["encoded"] == here["encoded"] == len(MATERIALS)
    assert _outputs(tmp_path / "there") == _outputs(tmp_path / "here")
    assert _leftovers(tmp_path) == []


def _without_timings(results: dict) -> dict:
    """A bench's results without what depends on the machine's speed."""
    cells = {}
    for key, cell in results["cells"].items():
        cells[key] = {k: v for k, v in cell.items() if not k.endswith("_s")}
    return {"cells": cells, "curves": results["curves"], "noise_floor": results["noise_floor"]}


def _plus_total(x: int, shared: np.ndarray) -> float:
    return float(x + shared.sum())


def test_pieces_that_read_lost_scattered_data_run_again(cluster):
    """Every worker that held a scattered object dies before its pieces run (as when the
    one worker that got the broadcast is killed while another restarts): the pieces are
    cancelled, and the executor sends the object again and runs them again."""
    shared = np.arange(4.0)
    handle = cluster.scatter(shared)
    cluster.client.restart()  # every worker replaced: the scattered data is gone
    assert handle.status != "finished", "the data survived the restart: the test did not test"
    assert cluster.map(_plus_total, [1, 2, 3], handle) == [7.0, 8.0, 9.0]
    assert dict(cluster.as_completed(_plus_total, [5], handle)) == {0: 11.0}
    cluster.release([handle])
    assert cluster._kept == {}


@pytest.mark.bench
def test_bench_survives_a_killed_worker(materials, ensemble_file, cluster, tmp_path):
    """The small grid's materials (a folder corpus) and ensemble keep the cells cheap."""

    def run(ex, name):
        cfg = BenchConfig(corpora=[str(materials)], split="all", max_materials=4,
                          models=["sparse:32", "naive"], curve_coeffs=[16],
                          ensemble=str(ensemble_file), render=False, speed=False,
                          stability=False, out=str(tmp_path / name))
        return Bench(cfg, progress=False).run(ex)

    here = run(None, "here")
    with WorkerKiller(cluster, "_cell_task") as killer:
        there = run(cluster, "there")
    assert killer.killed is not None, "no worker was killed: the test did not test"
    assert len(there["cells"]) == 8
    assert all(c["status"] == "finished" for c in there["cells"].values()), there["cells"]
    assert _without_timings(there) == _without_timings(here)


def _train_args(out: Path, ckpt: Path, *extra: str) -> list[str]:
    """A small training run: the built-in corpus on the small grid, two sparsities."""
    return ["train", "--corpus", "mitsuba", "--grid", *map(str, SMALL), "--taus", "8",
            "--dicts", "2", "--iterations", "3", "--reassign-every", "2", "--tol", "0",
            "--checkpoint-dir", str(ckpt), "-o", str(out), *extra]


@pytest.fixture(scope="module")
def reference_id(tmp_path_factory) -> str:
    """The ensemble id of the small training run, undisturbed and in this process."""
    folder = tmp_path_factory.mktemp("reference")
    assert main(_train_args(folder / "ref.npz", folder / "ckpt")) == 0
    return Ensemble.load(folder / "ref.npz").id


@pytest.mark.train
def test_training_stops_when_a_worker_dies_and_resumes(cluster, reference_id, tmp_path,
                                                       capsys):
    """A worker killed mid-iteration takes its shards of tensors with it: the command
    stops with one line (exit 2, no output) and the same command then resumes from the
    checkpoint to the undisturbed run's ensemble."""
    out, ckpt = tmp_path / "ens.npz", tmp_path / "ckpt"
    args = _train_args(out, ckpt, "--scheduler", cluster.client.scheduler.address)
    capsys.readouterr()
    with WorkerKiller(cluster, "shard_", when=ckpt / "tau-8.npz") as killer:
        status = main(args)
    assert killer.killed is not None, "no worker was killed: the test did not test"
    err = capsys.readouterr().err  # progress bars, then the message
    said = [ln for ln in err.splitlines() if "sparse-brdf:" in ln]
    assert status == 2, err
    assert len(said) == 1 and "error: a Dask worker was lost" in said[0], err
    assert not out.exists() and _leftovers(tmp_path) == []
    cluster.client.wait_for_workers(2, timeout=60)
    assert main(args) == 0
    assert Ensemble.load(out).id == reference_id


def test_training_killed_with_sigkill_resumes_bit_identical(reference_id, tmp_path):
    """``sparse-brdf train`` killed with SIGKILL once its first checkpoint exists, then
    run again with the same command: the ensemble of the undisturbed run, bit for bit."""
    out, ckpt = tmp_path / "ens.npz", tmp_path / "ckpt"
    args = [*CLI, *_train_args(out, ckpt)]
    proc = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while not (ckpt / "tau-8.npz").exists() and time.monotonic() < deadline:
        time.sleep(0.002)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait(timeout=30) == -signal.SIGKILL  # killed while running, not finished
    assert not out.exists()
    done = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert Ensemble.load(out).id == reference_id


# ------------------------------------------------------------------ concurrent writers


def test_two_batches_writing_one_folder_lose_nothing(materials, ensemble_file, tmp_path):
    """Two ``encode`` processes started at once on one output folder: every output is
    there, complete and the bytes of a lone run; no temporary file is left; the summary
    names every material."""
    alone, shared = tmp_path / "alone", tmp_path / "shared"
    args = ["encode", str(materials), "--coeffs", "16", "--ensemble", str(ensemble_file)]
    assert main([*args, "-o", str(alone)]) == 0
    procs = [subprocess.Popen([*CLI, *args, "-o", str(shared)], cwd=ROOT,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(2)]
    results = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], results
    assert _outputs(shared) == _outputs(alone)
    for path in shared.glob("*.sbrdf"):
        load_sbrdf(path, Ensemble.load(ensemble_file))
    assert _leftovers(tmp_path) == []
    summary = json.loads((shared / "summary.json").read_text())
    assert sorted(r["material"] for r in summary["rows"]) == sorted(MATERIALS)
    assert all(r["status"] in ("encoded", "skipped") for r in summary["rows"])
    assert summary["encoded"] + summary["skipped"] == len(MATERIALS)
