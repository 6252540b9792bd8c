"""The two calls docs/architecture.md follows ("Two calls, followed") are the calls the code
makes: each command runs in a fresh process under a profiler that records every call
from one file of the package (``sparse_brdf/``, ``mitsuba_plugin/``) into another, and the
files, their order, the first function entered in each, the climbs back up and the
figures must be those the guide draws. The guide's tables are read from the guide itself,
so that it and the code cannot drift apart."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import SMALL, random_orthonormal
from sparse_brdf.brdf import BRDF
from sparse_brdf.cli.files import encode_file
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coords import geometric_valid
from sparse_brdf.sources.merl import write_merl

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "architecture.md"
SECTION = "## Two calls, followed"

# Run in a fresh process: argv[1] the JSON file to write, the rest the command's arguments.
# It records (caller file, callee file, function) for each call that enters a file of the
# package from another one (the caller: the nearest frame in the package, None for the
# command's entry). Module bodies run by imports and the building of the parser are not
# part of the call and are left out. One thread does all the work: the thread pool holds
# one thread (it then maps inline) and Mitsuba loads the scene serially, so that every
# call is seen; the files crossed are the same as with threads.
TRACER = r"""
import functools, json, os, sys
import mitsuba
import sparse_brdf
from sparse_brdf.cli import main

mitsuba.load_string = functools.partial(mitsuba.load_string, parallel=False)
render, at_render = mitsuba.render, []

def marked_render(*args, **kwargs):  # where the calls made at render time start and end
    at_render.append(len(edges))
    try:
        return render(*args, **kwargs)
    finally:
        at_render.append(len(edges))

mitsuba.render = marked_render
root = os.path.dirname(os.path.dirname(sparse_brdf.__file__)) + os.sep
ours = tuple(root + p + os.sep for p in ("sparse_brdf", "mitsuba_plugin"))
edges, skip = [], [0]

def ours_rel(frame):
    while frame is not None and not frame.f_code.co_filename.startswith(ours):
        frame = frame.f_back
    return None if frame is None else frame.f_code.co_filename[len(root):]

def profile(frame, event, arg):
    if event not in ("call", "return"):
        return
    code = frame.f_code
    if code.co_name in ("<module>", "build_parser"):
        skip[0] += 1 if event == "call" else -1
        return
    if event == "return" or skip[0] or not code.co_filename.startswith(ours):
        return
    callee, caller = code.co_filename[len(root):], ours_rel(frame.f_back)
    edge = [caller, callee, code.co_name]
    if caller != callee and (not edges or edges[-1] != edge):
        edges.append(edge)

sys.setprofile(profile)
try:
    status = main(sys.argv[2:])
finally:
    sys.setprofile(None)
with open(sys.argv[1], "w") as f:
    json.dump({"status": status, "edges": edges, "at_render": at_render}, f)
"""


def trace_command(argv: list[str], cwd: Path) -> tuple[list, list[int]]:
    """The calls between the package's files that ``sparse-brdf ARGV`` makes, in order, as
    (caller, callee, function), and where the calls made inside ``mi.render`` start and
    end in that list (empty for a command that renders nothing)."""
    out = cwd / "calls.json"
    env = {**os.environ, "SPARSE_BRDF_THREADS": "1"}
    run = subprocess.run([sys.executable, "-c", TRACER, str(out), *argv], cwd=cwd, env=env,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-3000:]
    got = json.loads(out.read_text())
    assert got["status"] == 0, run.stderr[-3000:]
    return [tuple(e) for e in got["edges"]], got["at_render"]


def path_of(edges) -> list[tuple[str, str, tuple[int, ...]]]:
    """The path of a call: (file, first function entered, climbs back up) for each file in
    the order the call first enters it. A climb back up is a call from a file to one the
    call entered before it (a higher layer, called back, or a file already left); each
    is listed once, as the 1-based numbers of its targets on the path."""
    order: dict[str, int] = {}
    first: dict[str, str] = {}
    for _, callee, fn in edges:
        if callee not in order:
            order[callee], first[callee] = len(order) + 1, fn
    climbs: dict[str, set[int]] = {f: set() for f in order}
    for caller, callee, _ in edges:  # a caller outside the path (None: the entry) climbs not
        if caller in order and order[callee] < order[caller]:
            climbs[caller].add(order[callee])
    return [(f, first[f], tuple(sorted(climbs[f]))) for f in order]


def short(path: str) -> str:
    """A file as the guide names it: sparse_brdf's without the package's folder."""
    return path.removeprefix("sparse_brdf/")


def figures(rows) -> tuple[int, int]:
    """(files crossed, climbs back up) of a path."""
    return len(rows), sum(len(c) for _, _, c in rows)


def drawn(rows, command: str) -> str:
    """A path as the guide draws it: a line with the command and its figures, then a row
    per file (number, file, first function, ``^`` and the rows it climbs back up to)."""
    n, climbs = figures(rows)
    lines = [f"{command}: {n} files, {climbs} climbs back up"]
    for i, (f, fn, up) in enumerate(rows, 1):
        tail = f"  ^ {' '.join(map(str, up))}" if up else ""
        lines.append(f"{i:2d} {short(f):<32} {fn}{tail}".rstrip())
    return "\n".join(lines)


HEADER = re.compile(r"^(sparse-brdf [^:]+): (\d+) files, (\d+) climbs back up$")
ROW = re.compile(r"^\s*(\d+) (\S+\.py)\s+(\S+)(?:\s+\^((?: \d+)+))?\s*$")


def guide_paths(text: str) -> dict[str, tuple[tuple[int, int], str, list]]:
    """The paths the guide draws in its section ``SECTION``, by the line that names each
    (its command): the stated figures, the line, the rows."""
    assert SECTION in text, f"docs/architecture.md has no section {SECTION!r}"
    section = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    paths = {}
    for block in re.findall(r"```\n(.*?)```", section, re.S):
        head, *rest = block.strip().splitlines()
        m = HEADER.match(head)
        if m is None:
            continue
        rows = []
        for line in rest:
            r = ROW.match(line)
            assert r, f"docs/architecture.md: a row that does not read as one: {line!r}"
            rows.append((int(r[1]), r[2], r[3], tuple(int(x) for x in (r[4] or "").split())))
        paths[m[1]] = ((int(m[2]), int(m[3])), m[1], rows)
    return paths


def differences(guide, rows) -> list[str]:
    """Where the guide's drawing of a path (from :func:`guide_paths`) differs from the
    measured ``rows``; empty when they agree."""
    (n, climbs), _, drawn_rows = guide
    want = [(i, short(f), fn, up) for i, (f, fn, up) in enumerate(rows, 1)]
    diffs = [f"row {a[0]}: the guide draws {a[1:]}, the code runs {b[1:]}"
             for a, b in zip(drawn_rows, want, strict=False) if a != b]
    if len(drawn_rows) != len(want):
        diffs.append(f"the guide draws {len(drawn_rows)} rows, the code crosses {len(want)} "
                     "files")
    if (n, climbs) != figures(rows):
        diffs.append(f"the guide states {n} files and {climbs} climbs back up, the code "
                     f"makes {figures(rows)[0]} and {figures(rows)[1]}")
    if (n, climbs) != (len(drawn_rows), sum(len(r[3]) for r in drawn_rows)):
        diffs.append("the guide's figures do not count its own rows")
    return diffs


ENCODE = "sparse-brdf encode in.binary -o out.sbrdf"
RENDER = "sparse-brdf render scene.xml"
AT_RENDER = f"{RENDER}, inside mi.render"


def mismatch(command: str, rows) -> str:
    """What differs between the guide's drawing of ``command`` and the measured ``rows``,
    with the path as the code runs it, ready to paste; empty when they agree."""
    paths = guide_paths(GUIDE.read_text())
    if command not in paths:
        return f"docs/architecture.md draws no path {command!r}:\n{drawn(rows, command)}"
    diffs = differences(paths[command], rows)
    return "\n".join([*diffs, "the path as the code runs it now:", drawn(rows, command)]
                     ) if diffs else ""


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """A small-grid material (.binary), an ensemble for its grid, its encoding and a
    4 x 4 pixel scene that renders it with ``sparse_brdf``."""
    d = tmp_path_factory.mktemp("paths")
    rng = np.random.default_rng(3)
    u = [np.stack([random_orthonormal(n, rng) for _ in range(2)]) for n in SMALL]
    Ensemble(*u, taus=np.array([16, 16])).save(d / "ens.npz")
    h = np.linspace(1.0, 0.0, SMALL[0])[:, None, None, None]
    values = np.broadcast_to(0.05 + 2.0 * h**8 * np.array([1.0, 0.5, 0.2]), (*SMALL, 3))
    write_merl(d / "in.binary", BRDF(values.astype(np.float32), geometric_valid(SMALL)))
    encode_file(d / "in.binary", d / "model.sbrdf", d / "ens.npz")
    (d / "scene.xml").write_text(f"""<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="2"/></integrator>
  <sensor type="perspective">
    <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/>
    </transform>
    <film type="hdrfilm"><integer name="width" value="4"/><integer name="height" value="4"/>
    </film>
    <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
  </sensor>
  <emitter type="constant"/>
  <shape type="sphere">
    <bsdf type="sparse_brdf" id="material">
      <string name="filename" value="{d / 'model.sbrdf'}"/>
      <string name="ensemble" value="{d / 'ens.npz'}"/>
    </bsdf>
  </shape>
</scene>
""")
    return d


def test_the_encode_path_is_the_one_drawn(inputs):
    """``sparse-brdf encode in.binary -o out.sbrdf``: command line, the library's
    boundary, the EncodeSpec, the encoder's modules, the file writer."""
    edges, _ = trace_command(["encode", "in.binary", "-o", "out.sbrdf", "--ensemble",
                              "ens.npz"], inputs)
    assert (inputs / "out.sbrdf").is_file()
    problem = mismatch(ENCODE, path_of(edges))
    assert not problem, problem


@pytest.mark.render
def test_the_render_path_is_the_one_drawn(inputs):
    """``sparse-brdf render scene.xml`` with a ``sparse_brdf`` material: command line,
    scene and render helpers, the plugin's loading, the decoders' layouts, lobe and
    budget, the Dr.Jit kernels at render time."""
    edges, (start, end) = trace_command(["render", "scene.xml"], inputs)
    assert (inputs / "scene.exr").is_file()
    assert path_of(edges[start:end]) != []
    problem = "\n\n".join(p for p in (mismatch(RENDER, path_of(edges)),
                                       mismatch(AT_RENDER, path_of(edges[start:end]))) if p)
    assert not problem, problem


# The checks can fail: a path measured from made-up calls, and a guide doctored.
CALLS = [(None, "sparse_brdf/cli/_entry.py", "main"),
         ("sparse_brdf/cli/_entry.py", "sparse_brdf/coding/spec.py", "build"),
         ("sparse_brdf/coding/spec.py", "sparse_brdf/params.py", "check"),
         ("sparse_brdf/cli/_entry.py", "sparse_brdf/coding/encode.py", "encode_with"),
         ("sparse_brdf/coding/encode.py", "sparse_brdf/parallel.py", "parallel_map"),
         ("sparse_brdf/parallel.py", "sparse_brdf/coding/encode.py", "<lambda>"),
         ("sparse_brdf/coding/encode.py", "sparse_brdf/coding/spec.py", "options"),
         ("sparse_brdf/coding/encode.py", "sparse_brdf/params.py", "check"),
         ("sparse_brdf/coding/encode.py", "sparse_brdf/coding/spec.py", "joint")]


def test_a_path_counts_files_in_order_and_climbs_back_up():
    rows = path_of(CALLS)
    assert rows == [("sparse_brdf/cli/_entry.py", "main", ()),
                    ("sparse_brdf/coding/spec.py", "build", ()),
                    ("sparse_brdf/params.py", "check", ()),
                    ("sparse_brdf/coding/encode.py", "encode_with", (2, 3)),
                    ("sparse_brdf/parallel.py", "parallel_map", (4,))]
    assert figures(rows) == (5, 3)


def test_a_guide_that_differs_from_the_code_fails():
    rows = path_of(CALLS)
    text = f"{SECTION}\n\n```\n{drawn(rows, 'sparse-brdf encode x')}\n```\n\n## Next\n"
    assert differences(guide_paths(text)["sparse-brdf encode x"], rows) == []
    doctored = [text.replace(" 4 coding/encode.py", " 4 coding/fill.py  "),  # another file
                text.replace("^ 2 3", "^ 2"),  # a climb left out
                text.replace("5 files", "4 files"),  # a figure wrong
                text.replace("^ 4\n", "^ 4\n 6 extra.py  f\n")]  # a file too many
    for bad in doctored:
        assert bad != text
        assert differences(guide_paths(bad)["sparse-brdf encode x"], rows) != [], bad
