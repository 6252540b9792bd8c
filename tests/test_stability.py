"""The stability suite: every case gets a status per method; failures never propagate."""

import numpy as np

from conftest import SMALL
from sparse_brdf.benchmark.stability import CASES, run_stability, stability_markdown
from sparse_brdf.compared.baselines import NaiveModel
from sparse_brdf.compared.compact import BRDFModel, Compact
from sparse_brdf.compared.sparse_model import SparseModel
from sparse_brdf.sources.load import load_brdf


class Exploding(BRDFModel):
    name = "exploding"

    def compress(self, brdf):
        raise RuntimeError("boom")


class NaNModel(BRDFModel):
    name = "nan"

    def compress(self, brdf):
        return Compact(self.name, 4, lambda: np.full(brdf.values.shape, np.nan))


def test_every_case_and_method_gets_a_status(tmp_path, small_ensemble):
    clean = load_brdf("mitsuba:plastic-blue-ggx-0.2", shape=SMALL)
    methods = [SparseModel(small_ensemble, 64), NaiveModel(), Exploding(), NaNModel()]
    rows = run_stability(clean, methods, tmp_path)
    assert len(rows) == len(CASES) * len(methods)
    by = {(r["case"], r["method"]): r for r in rows}
    # non-finite input is refused by the reader with a message naming the file
    for case in ("NaN entries", "inf entries"):
        r = by[(case, "naive")]
        assert r["status"] == "clear error" and "NaN or inf" in r["message"]
        assert "case" in r["message"] and ".binary" in r["message"]
    # one method's failure is recorded, the others still finish
    assert by[("noise 1%", "exploding")]["status"] == "failed"
    assert "boom" in by[("noise 1%", "exploding")]["message"]
    assert by[("noise 1%", "nan")]["status"] == "failed"
    assert by[("noise 1%", "naive")]["status"] == "finished"
    # more noise, lower SNR against the clean material
    assert by[("noise 1%", "naive")]["snr"] > by[("noise 50%", "naive")]["snr"]
    # negative entries are unmeasured bins, as in MERL files
    assert by[("negative entries", "naive")]["status"] == "finished"
    table = stability_markdown(rows)
    assert len(table) == 2 + len(CASES) and "exploding" in table[0]
