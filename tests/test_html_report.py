"""The bench's HTML report: self-contained, and working in a browser (headless Chromium):
the page loads without console errors, its viewer flips between reference and model and
shows the FLIP map, its tables sort, and a screenshot shows it."""

from __future__ import annotations

import html
import json
import os
import re
import shutil
import subprocess

import numpy as np
import pytest

from sparse_brdf.benchmark.bench import Bench
from sparse_brdf.benchmark.bench_config import BenchConfig

pytestmark = [pytest.mark.render, pytest.mark.bench]  # the module's fixture runs a bench


def _chromium() -> str | None:
    """A Chromium to run headless: $SPARSE_BRDF_CHROMIUM, else chromium on the PATH."""
    for name in (os.environ.get("SPARSE_BRDF_CHROMIUM"), "chromium", "chromium-browser",
                 "google-chrome"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """A tiny bench's output folder: one material, naive and the table, the studio scene
    and one angle of the one-light set, 16x16 at 2 spp."""
    out = tmp_path_factory.mktemp("html") / "bench"
    cfg = BenchConfig(corpora=["mitsuba"], max_materials=1, models=["naive", "tabulated"],
                      scenes=["sphere.xml", "sphere_light.xml:lightangle=70"], res=16, spp=2,
                      curve_coeffs=[16], stability=False, speed=False, out=str(out))
    Bench(cfg, progress=False).run()
    return out


def test_the_page_is_self_contained(report):
    page = (report / "report.html").read_text()
    assert "default-src 'none'" in page  # the browser may fetch nothing
    assert not re.search(r"""(src|href)\s*=\s*["'](?!data:|#)""", page)
    assert page.count("data:image/jpeg;base64,") >= 8  # reference, renders, both maps, bars
    assert "data:image/png;base64," in page  # the charts
    data = json.loads(re.search(r'<script type="application/json" id="bench-data">(.*?)'
                                r"</script>", page, re.S).group(1).replace("<\\/", "</"))
    cells = data["viewer"]["sphere_light-lightangle=70"]
    (material,) = cells
    assert set(cells[material]["models"]) == {"naive", "tabulated"}
    assert cells[material]["models"]["tabulated"]["flip"] == 0.0
    assert all(m["diff_map"].startswith("data:image/jpeg") for m in cells[material]["models"]
               .values())
    assert set(data["bars"]) == {"flip", "diff"}


#: A number as report.md writes it: 12, 0.049, -3.5, 4.98e+07.
NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:e[-+]\d+)?(?!\w)")


def test_every_number_of_report_md_is_in_report_html(report, tmp_path):
    """Whatever report.md states (tables, speeds and their spread, noise floors, the
    stability table), report.html states too, in the same digits."""
    from sparse_brdf.benchmark.html_report import write_html_report
    from sparse_brdf.benchmark.report import write_report
    from sparse_brdf.benchmark.results_file import read_results

    out = tmp_path / "bench"
    shutil.copytree(report, out)
    results = read_results(out)
    # the fixture measures no speed and runs no stability: give it both
    results["speed"] = {"naive": 4.98e7, "tabulated": 2.31e7}
    results["speed_spread"] = {m: {"min": v * 0.9, "max": v * 1.05, "repeats": 7, "n": 4096,
                                   "settled": True} for m, v in results["speed"].items()}
    results["config"]["speed"] = True
    results["stability"] = {"material": "mitsuba/x", "rows": [
        {"case": "noise 1%", "method": "naive", "status": "finished", "snr": 31.46},
        {"case": "noise 1%", "method": "tabulated", "status": "failed"}]}
    write_report(results, out)
    write_html_report(results, out)
    md = (out / "report.md").read_text()
    page = re.sub(r"data:image/[^\"']+", "", (out / "report.html").read_text())
    text = html.unescape(re.sub(r"<[^>]+>", " ", page))
    numbers = {n: line for line in md.splitlines() if not line.startswith("![")
               for n in NUMBER.findall(line)}
    assert {"4.98e+07", "4.48e+07", "5.23e+07", "31.5"} <= set(numbers)  # the test can see
    missing = {n: line[:80] for n, line in numbers.items() if n not in text}
    assert missing == {}


def test_the_page_in_headless_chromium(report, tmp_path):
    browser = _chromium()
    if browser is None:
        pytest.skip("no Chromium to run headless: install Debian's chromium "
                    "(apt-get install chromium) or set SPARSE_BRDF_CHROMIUM")
    url = (report / "report.html").as_uri() + "#selftest"
    common = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
              "--virtual-time-budget=5000", f"--user-data-dir={tmp_path / 'profile'}"]
    dom = subprocess.run([*common, "--enable-logging=stderr", "--v=0", "--dump-dom", url],
                         capture_output=True, text=True, timeout=120)
    assert dom.returncode == 0, dom.stderr[-2000:]
    console = [ln for ln in dom.stderr.splitlines() if ":CONSOLE" in ln]
    assert not console, console  # the page logs nothing: no error, no blocked fetch
    found = re.search(r'<pre id="selftest-result">(.*?)</pre>', dom.stdout, re.S)
    assert found and found.group(1), "the page's self-check did not run"
    check = json.loads(found.group(1).replace("&quot;", '"'))
    assert check["ok"] and not check["errors"], check
    assert set(check["checks"]) >= {"flips_to_reference", "flips_back", "flip_map", "sorts",
                                    "flip_colour_bar", "diff_map", "map_off", "exposure",
                                    "key_with_menu_focused"}
    # the sort was checked on a column whose values differ, reordering the rows both ways
    sort = check["sort"]
    assert len(set(sort["before"])) >= 2, sort
    assert sort["ascending"] == sorted(sort["before"]), sort
    assert sort["descending"] == sorted(sort["before"], reverse=True), sort
    assert sort["ascending"] != sort["descending"], sort
    shot = tmp_path / "shot.png"
    # tall enough that the first viewer is whole on screen however the fonts wrap the text
    run = subprocess.run([*common, "--window-size=1000,1600", f"--screenshot={shot}", url],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and shot.is_file(), run.stderr[-2000:]
    from matplotlib import image as mimage

    pixels = mimage.imread(shot)[..., :3]
    assert pixels.shape[:2] == (1600, 1000)
    assert pixels.std() > 0.05  # a page, not a blank frame
    # the viewer's dark renders fill much of its 384 x 384 frame: 55,000 such pixels here,
    # none on a page without it
    assert (pixels.max(-1) < 0.05).sum() > 20_000
    assert np.isfinite(pixels).all()
