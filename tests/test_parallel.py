"""Where work runs (``sparse_brdf/parallel.py``): batch encoding, the bench and training
give the same results in this process and on a local Dask cluster of 2 processes; Dask is
never imported unless a cluster is asked for."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.batch import batch_sources, encode_batch, is_batch
from sparse_brdf.benchmark.bench import Bench
from sparse_brdf.benchmark.bench_config import BenchConfig
from sparse_brdf.cli import main
from sparse_brdf.coding.fileformat import load_sbrdf
from sparse_brdf.parallel import InProcess, executor, start_executor
from sparse_brdf.sources.load import load_brdf
from sparse_brdf.sources.merl import write_merl
from sparse_brdf.training import _shards as shards_mod
from sparse_brdf.training.train import train_dictionaries

ROOT = Path(__file__).resolve().parents[1]
STATE = ("u1", "u2", "u3", "labels", "codes_idx", "codes_val", "errors")


@pytest.fixture(scope="module")
def cluster():
    """One local cluster of 2 worker processes for the module, always shut down."""
    pytest.importorskip("dask.distributed")
    ex = start_executor(workers=2)
    try:
        yield ex
    finally:
        ex.close()


def _square(x, offset=0):
    return x * x + offset


def test_cli_and_help_do_not_import_dask():
    code = ("import sys, contextlib, io, sparse_brdf, sparse_brdf.cli as c\n"
            "with contextlib.suppress(SystemExit), contextlib.redirect_stdout(io.StringIO()):\n"
            "    c.main(['encode', '--help'])\n"
            "print(sorted(m for m in ('dask', 'distributed') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT).stdout.strip()
    assert out == "[]"


def test_executors_keep_input_order(cluster):
    with executor() as ex:
        assert isinstance(ex, InProcess)
        here = ex.map(_square, range(7), 1)
    assert here == [i * i + 1 for i in range(7)]
    offset = cluster.scatter(1)
    assert cluster.map(_square, range(7), offset) == here
    assert sorted(cluster.as_completed(_square, range(7), offset)) == list(enumerate(here))
    placed = cluster.place(np.arange, [(3,), (5,)])
    assert {p.worker for p in placed} == set(cluster.workers)  # one per worker, in turn
    assert [int(v) for v in cluster.run_on(placed, np.sum, None)] == [3, 10]
    cluster.release(placed)
    assert cluster.stats["bytes_received"] > 0 and cluster.stats["tasks"] > 0
    with pytest.raises(ValueError, match="not both"):
        start_executor(workers=2, scheduler="tcp://127.0.0.1:1")


# ------------------------------------------------------------------ batch encoding


@pytest.fixture(scope="module")
def small_materials(tmp_path_factory):
    """Four built-in materials on the small grid as .binary files, and a broken file."""
    folder = tmp_path_factory.mktemp("materials")
    for name in ("au-ggx-0.08", "plastic-red-ggx-0.05", "cu-ggx-0.35", "diffuse-grey"):
        write_merl(folder / f"{name}.binary", load_brdf(f"mitsuba:{name}", shape=SMALL))
    (folder / "broken.binary").write_bytes(b"not a MERL file")
    return folder


@pytest.fixture(scope="module")
def small_ensemble_file(small_ensemble, tmp_path_factory):
    path = tmp_path_factory.mktemp("ens") / "small.npz"
    small_ensemble.save(path)
    return path


def test_batch_sources(small_materials, tmp_path):
    assert is_batch(small_materials) and is_batch(f"{small_materials}/*.binary")
    assert not is_batch(small_materials / "plastic-red-ggx-0.05.binary")
    assert len(batch_sources(small_materials)) == 5
    found = batch_sources(f"{small_materials}/p*.binary")
    assert [p.stem for p in found] == ["plastic-red-ggx-0.05"]
    with pytest.raises(FileNotFoundError, match="no materials"):
        batch_sources(f"{tmp_path}/*.h5")
    (tmp_path / "a.binary").write_bytes(b"")
    (tmp_path / "a.h5").write_bytes(b"")
    with pytest.raises(ValueError, match="output names"):
        batch_sources(tmp_path)


def test_batch_encode_resumes_and_reports_failures(small_materials, small_ensemble_file,
                                                   tmp_path, capsys):
    out = tmp_path / "out"
    args = ["encode", str(small_materials), "-o", str(out), "--coeffs", "16",
            "--ensemble", str(small_ensemble_file)]
    assert main(args) == 1  # one material failed: exit status 1, the others are encoded
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["encoded"], summary["skipped"], summary["failed"]) == (4, 0, 1)
    rows = {r["material"]: r for r in summary["rows"]}
    assert "broken" in rows["broken"]["error"] or "MERL" in rows["broken"]["error"]
    assert "failed: " in capsys.readouterr().err
    ok = rows["plastic-red-ggx-0.05"]
    assert ok["bytes"] == (out / "plastic-red-ggx-0.05.sbrdf").stat().st_size
    assert np.isfinite(ok["snr_proxy_db"]) and ok["transform"] and ok["seconds"] > 0
    csv_lines = (out / "summary.csv").read_text().splitlines()
    assert csv_lines[0].startswith("material,source,output,status,snr_proxy_db,bytes")
    assert len(csv_lines) == 6
    before = {p.name: p.read_bytes() for p in out.glob("*.sbrdf")}
    (out / "diffuse-grey.sbrdf").write_bytes(b"truncated")  # an unfinished output
    assert main(args) == 1
    again = json.loads((out / "summary.json").read_text())
    assert (again["encoded"], again["skipped"], again["failed"]) == (1, 3, 1)
    skipped = {r["material"]: r for r in again["rows"]}["plastic-red-ggx-0.05"]
    assert skipped["status"] == "skipped" and skipped["snr_proxy_db"] == ok["snr_proxy_db"]
    assert {p.name: p.read_bytes() for p in out.glob("*.sbrdf")} == before
    # other options into the same folder are refused rather than mixed
    assert main([*args[:-4], "--coeffs", "32", "--ensemble", str(small_ensemble_file)]) == 2


def test_batch_encode_is_bit_identical_on_workers(small_materials, small_ensemble, tmp_path,
                                                  cluster):
    pattern = f"{small_materials}/*[!n].binary"  # every material but broken.binary
    opts = {"n_coeffs": 24}
    here = encode_batch(pattern, tmp_path / "here", small_ensemble, opts, progress=False)
    there = encode_batch(pattern, tmp_path / "there", small_ensemble, opts, cluster,
                         progress=False)
    assert here["encoded"] == there["encoded"] == 4
    for name in ("au-ggx-0.08", "plastic-red-ggx-0.05", "cu-ggx-0.35", "diffuse-grey"):
        a, b = (tmp_path / d / f"{name}.sbrdf" for d in ("here", "there"))
        assert a.read_bytes() == b.read_bytes(), name
        load_sbrdf(b, small_ensemble)
    keep = ("material", "status", "snr_proxy_db", "bytes", "transform", "coefficients")
    assert ([{k: r[k] for k in keep} for r in here["rows"]]
            == [{k: r[k] for k in keep} for r in there["rows"]])
    assert "2 Dask workers" in there["where"]


def test_batch_encode_command_on_a_cluster(small_materials, small_ensemble_file, tmp_path,
                                           cluster, capsys):
    address = cluster.client.scheduler.address
    out = tmp_path / "out"
    assert main(["encode", f"{small_materials}/[dp]*.binary", "-o", str(out), "--coeffs",
                 "16", "--ensemble", str(small_ensemble_file), "--scheduler", address]) == 0
    assert "2 encoded, 0 skipped" in capsys.readouterr().out
    assert sorted(p.stem for p in out.glob("*.sbrdf")) == ["diffuse-grey",
                                                           "plastic-red-ggx-0.05"]


# ------------------------------------------------------------------ training


@pytest.mark.train
def test_training_is_bit_identical_on_workers(small_training, cluster, tmp_path,
                                              monkeypatch):
    """Masked, seeded training of 40 tensors in 3 shards: the same dictionaries, codes and
    objectives in-process and on 2 workers; a run resumed on the cluster from an
    in-process checkpoint ends where an uninterrupted run does."""
    monkeypatch.setattr(shards_mod, "SHARD_TENSORS", 16)  # shards are cut here, not there
    x = small_training[:40]
    kw = dict(tau=12, n_dicts=3, tol=0, seed=4, progress=False, reassign_every=2)
    here = train_dictionaries(x, n_iter=3, **kw)
    there = train_dictionaries(x, n_iter=3, executor=cluster, **kw)
    for k in STATE:
        np.testing.assert_array_equal(getattr(here, k), getattr(there, k), err_msg=k)
    assert ([h["objective"] for h in here.history]
            == [h["objective"] for h in there.history])
    moved = there.history[-1]
    assert moved["bytes_to_workers"] > 0 and moved["bytes_from_workers"] > 0
    assert "bytes_to_workers" not in here.history[-1]
    ckpt = tmp_path / "ckpt.npz"
    train_dictionaries(x, n_iter=2, checkpoint=ckpt, **kw)
    resumed = train_dictionaries(x, n_iter=3, checkpoint=ckpt, executor=cluster, **kw)
    assert resumed.iteration == 3
    for k in STATE:
        np.testing.assert_array_equal(getattr(here, k), getattr(resumed, k), err_msg=k)


@pytest.mark.train
def test_unmasked_random_training_on_workers(small_training, cluster):
    x = small_training[:20]
    kw = dict(tau=8, n_dicts=2, n_iter=2, tol=0, seed=1, progress=False, masked=False,
              init="random")
    here, there = (train_dictionaries(x, executor=ex, **kw) for ex in (None, cluster))
    for k in STATE:
        np.testing.assert_array_equal(getattr(here, k), getattr(there, k), err_msg=k)


@pytest.mark.train
def test_train_command_on_a_cluster(cluster, tmp_path):
    out = tmp_path / "ens.npz"
    assert main(["train", "--corpus", "mitsuba", "--grid", *map(str, SMALL), "--taus", "8",
                 "--dicts", "2", "--iterations", "1", "--scheduler",
                 cluster.client.scheduler.address, "-o", str(out)]) == 0
    from sparse_brdf.coding.ensemble import Ensemble

    assert "Dask workers" in Ensemble.load(out).meta["where"]


# ------------------------------------------------------------------ bench


@pytest.mark.bench
@pytest.mark.render
def test_bench_gives_the_same_results_on_workers(tmp_path, cluster):
    def run(ex, name):
        cfg = BenchConfig(corpora=["mitsuba"], split="test", max_materials=1,
                          models=["sparse:32", "naive"], curve_coeffs=[16, 64],
                          scenes=["sphere.xml"], spp=4, res=16, speed_evals=4096,
                          stability=False, out=str(tmp_path / name))
        return Bench(cfg, progress=False).run(ex)

    here, there = run(None, "here"), run(cluster, "there")
    timing = ("fit_s", "render_s")
    for cells in (here["cells"], there["cells"]):
        for c in cells.values():
            assert c["status"] == "finished", c
            for t in timing:
                c.pop(t, None)
                for r in c.get("renders", {}).values():
                    r.pop(t, None)
    assert here["cells"] == there["cells"]
    assert here["curves"] == there["curves"]
    assert here["noise_floor"] == there["noise_floor"]
    assert set(here["speed"]) == set(there["speed"]) == {"sparse-32", "naive"}
    assert (tmp_path / "there" / "report.md").is_file()


def test_an_interrupted_map_does_not_hang_the_exit():
    """Ctrl-C can land inside ThreadPoolExecutor's thread start, after the worker thread
    runs but before concurrent.futures registers it for the exit: no one would wake that
    thread and the interpreter's exit would wait on it forever. Here the interrupt is put
    exactly there; parallel_map must leave a process that exits."""
    code = (
        "import concurrent.futures.thread as cft\n"
        "from sparse_brdf.parallel import parallel_map\n"
        "start = cft.ThreadPoolExecutor._adjust_thread_count\n"
        "def interrupted(self):\n"
        "    start(self)\n"
        "    for t in list(self._threads):\n"  # the state the race leaves: unregistered
        "        cft._threads_queues.pop(t, None)\n"
        "    raise KeyboardInterrupt\n"
        "cft.ThreadPoolExecutor._adjust_thread_count = interrupted\n"
        "try:\n"
        "    list(parallel_map(abs, range(8)))\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted')\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, env={**os.environ, "SPARSE_BRDF_THREADS": "2"})
    assert (run.returncode, run.stdout, run.stderr) == (0, "interrupted\n", "")
