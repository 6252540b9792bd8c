"""The bench report as one self-contained HTML page (``report.html`` beside ``report.md``).

Everything is inside the file (styles, script, every image as a data URI), so it opens
from disk with no network and can be mailed or archived as one file:

- per scene, the models' table and the per-material table, sortable by any column (click
  a header; again for the reverse order);
- per scene, a viewer of every material and model: the reference and the model's render
  in one frame, a slider wiping from one to the other, ``F`` (or the button) flipping
  between them, ``M`` toggling the model's HDR-FLIP error map (magma, 0 to 1) and ``D``
  its difference map (``|ref - img| x 10``, jet, 0 to 1) in place of its render, each
  map with its colour bar, and a display exposure slider (stops, applied to the
  tone-mapped renders); the keys work whatever has focus (a menu, the slider, a table);
  renders are tone-mapped as the report's figures (x / (1 + x), gamma 2.2);
- the report's charts (its PNGs, but for the render figures, which the viewer replaces).

Opened as ``report.html#selftest`` the page checks itself (a flip, with a menu focused
too, the FLIP and difference maps and their colour bars, the exposure, a
column of differing values sorted up then down, its rows reordered) and writes the
outcome into the element ``#selftest-result`` (what the test suite reads through
headless Chromium, ``tests/test_html_report.py``).
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
import re
from pathlib import Path

import numpy as np

from ..evaluation.images import read_exr
from ..fileio import atomic_write
from ..metrics import OBJECT_ONLY, WHOLE_IMAGE
from .report import (
    failed_cells,
    flip_map_path,
    noise_floor_means,
    provenance_rows,
    scenes_of,
    seeds_sentence,
    speed_settings,
    summary_table,
    tone,
)

__all__ = ["write_html_report"]

#: JPEG quality of the renders and maps in the viewer (a 128x128 render: about 6 kB).
_JPEG_QUALITY = 92


def _image_uri(rgb: np.ndarray | None = None, scalar: np.ndarray | None = None,
               cmap: str = "magma") -> str:
    """A data URI of a JPEG: ``rgb`` in [0, 1] (H, W, 3), or ``scalar`` in [0, 1] (H, W)
    through the colour map ``cmap``."""
    import matplotlib  # lazy: matplotlib takes ~0.4 s to import; only reports need it

    matplotlib.use("Agg")
    from matplotlib import image as mimage

    buf = io.BytesIO()
    if scalar is not None:
        mimage.imsave(buf, np.clip(scalar, 0, 1), cmap=cmap, vmin=0, vmax=1, format="jpeg",
                      pil_kwargs={"quality": _JPEG_QUALITY})
    else:
        mimage.imsave(buf, np.clip(rgb, 0, 1), format="jpeg",
                      pil_kwargs={"quality": _JPEG_QUALITY})
    return "data:image/jpeg;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _png_uri(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _num(x) -> float | str | None:
    """A figure for JSON: None for none or nan, ``"inf"`` for an infinite SNR (a model
    identical to the reference)."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return None
    return float(x) if math.isfinite(x) else ("inf" if x > 0 else "-inf")


def viewer_data(results: dict, out: Path, scene: str) -> dict:
    """Per material of ``scene``: the reference render and each model's render, FLIP map
    and difference map (data URIs) with its figures; materials without a reference render
    are left out."""
    work = out / "work" / scene
    mats: dict = {}
    refs: dict = {}
    cells = sorted(results["cells"].values(), key=lambda c: (c["material"], c["model"]))
    for c in cells:
        stem = c["material"].replace("/", "__")
        ref_p, img_p = work / f"{stem}__reference.exr", work / f"{stem}__{c['model']}.exr"
        if not (ref_p.is_file() and img_p.is_file()):
            continue
        if c["material"] not in refs:
            refs[c["material"]] = read_exr(ref_p)
        ref, img = refs[c["material"]], read_exr(img_p)
        entry = mats.setdefault(c["material"], {"reference": _image_uri(tone(ref)),
                                                "models": {}})
        fp = flip_map_path(out, scene, c["material"], c["model"])
        figures = (c.get("renders") or {}).get(scene, {})
        entry["models"][c["model"]] = {
            "render": _image_uri(tone(img)),
            # linear radiance, as report.md's figures: |ref - img| x 10, jet from 0 to 1
            "diff_map": _image_uri(scalar=np.abs(ref - img).mean(-1) * 10, cmap="jet"),
            "flip_map": _image_uri(scalar=np.load(fp).astype(np.float32)) if fp.is_file() else None,
            **{k: _num(figures.get(k)) for k in ("snr_object", "snr_whole", "flip")}}
    return mats


def _cell(value, fmt: str) -> str:
    """A table cell; numbers carry their value for sorting."""
    if isinstance(value, str):
        return f'<td class="text">{html.escape(value)}</td>'
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return '<td data-v="">-</td>'
    sort = "1e300" if value == math.inf else repr(float(value))
    return f'<td data-v="{sort}">{format(value, fmt)}</td>'


def _table(head: list[str], rows: list[list[str]]) -> str:
    ths = "".join(f"<th>{html.escape(h)}</th>" for h in head)
    trs = "".join(f"<tr>{''.join(r)}</tr>" for r in rows)
    return f'<table class="sortable"><thead><tr>{ths}</tr></thead><tbody>{trs}</tbody></table>'


def _model_table(results: dict, scene: str) -> str:
    cols = [("bytes", ".0f"), ("evals_per_s", ".3g"), ("evals_min", ".3g"),
            ("evals_max", ".3g"), ("fit_s", ".2f"), ("rae", ".4f"), ("cos_snr", ".1f"),
            *((f"{form}_{stat}", ".1f") for form in ("snr_object", "snr_whole")
              for stat in ("mean", "std", "min", "max")),
            ("flip_mean", ".3f"), ("flip_max", ".3f"), ("render_s", ".2f")]
    rows = summary_table(results, scene)
    seeded = [k for k in ("snr_object_se", "snr_whole_se", "flip_se")
              if any(k in r for r in rows)]  # several seeds: standard errors
    cols += [(k, ".3f" if k == "flip_se" else ".1f") for k in seeded]
    head = ["model", "materials", "failed", "bytes", "evals/s", "evals/s min",
            "evals/s max", "fit (s)", "RAE", "cos-SNR (dB)",
            *(f"{form} {stat} (dB)" for form in ("obj", "whole")
              for stat in ("mean", "std", "min", "max")),
            "FLIP mean", "FLIP max", "render (s)",
            *(_SE_HEADS[k] for k in seeded)]
    rows = [[_cell(r["model"], ""), _cell(r["n"], "d"), _cell(r["failed"], "d"),
             *('<td data-v="">failed</td>' if k.startswith("evals") and r["n"] == 0
               else _cell(r.get(k, math.nan), f) for k, f in cols)]
            for r in rows]
    return f"<p>{html.escape(speed_settings(results))}</p>" + _table(head, rows)


def _noise_floor(results: dict, scene: str) -> str:
    """The noise floor of ``scene``'s references, as report.md states it."""
    nf = noise_floor_means(results, scene)
    if nf is None:
        return ""
    cfg = results["config"]
    return (f"<p>Noise floor (two reference renders, seeds {cfg['seed']} and "
            f"{cfg['noise_seed']}): {OBJECT_ONLY} mean {nf['snr_object']:.1f} dB, "
            f"{WHOLE_IMAGE} mean {nf['snr_whole']:.1f} dB.</p>")


def _stability(results: dict) -> list[str]:
    """The stability section: each perturbation's cosine-weighted SNR per model."""
    st = results.get("stability")
    if not st:
        return []
    rows = st["rows"]
    methods = list(dict.fromkeys(r["method"] for r in rows))
    cell = {(r["case"], r["method"]): r for r in rows}
    body = [[_cell(case, ""), *(_cell(cell[(case, m)]["snr"], ".1f")
                                if cell[(case, m)]["status"] == "finished"
                                else _cell(cell[(case, m)]["status"], "") for m in methods)]
            for case in dict.fromkeys(r["case"] for r in rows)]
    return [f"<h2>Stability</h2><p>Perturbations of {html.escape(st['material'])}; "
            "cosine-weighted SNR (dB) against the clean BRDF, or the outcome.</p>",
            _table(["case", *methods], body)]


#: The columns of the standard errors over several seeds.
_SE_HEADS = {"snr_object_se": "obj ± (dB)", "snr_whole_se": "whole ± (dB)",
             "flip_se": "FLIP ±"}


def _material_table(results: dict, scene: str) -> str:
    rows = []
    cells = sorted(results["cells"].values(), key=lambda c: (c["material"], c["model"]))
    seeded = [k for k in _SE_HEADS
              if any(k in ((c.get("renders") or {}).get(scene) or {}) for c in cells)]
    for c in cells:
        s = (c.get("renders") or {}).get(scene, {})
        rows.append([_cell(c["material"], ""), _cell(c["model"], ""),
                     _cell(s.get("snr_object", math.nan), ".1f"),
                     _cell(s.get("snr_whole", math.nan), ".1f"),
                     _cell(math.nan if s.get("flip") is None else s["flip"], ".3f"),
                     _cell(s.get("render_s", math.nan), ".2f"),
                     _cell(c.get("rae", math.nan), ".4f"),
                     _cell(f"{c['status']}: {c['error']}" if c.get("error") else c["status"],
                           ""),
                     *(_cell(s.get(k), ".3f" if k == "flip_se" else ".1f")
                       for k in seeded)])
    return _table(["material", "model", "SNR obj (dB)", "SNR whole (dB)", "HDR-FLIP",
                   "render (s)", "RAE", "status", *(_SE_HEADS[k] for k in seeded)], rows)


def _viewer(scene: str, index: int) -> str:
    return f'''<div class="viewer" id="viewer-{index}" data-scene="{html.escape(scene)}"
 tabindex="0">
 <div class="controls">
  <label>material <select class="material"></select></label>
  <label>model <select class="model"></select></label>
  <button class="flip" title="key F">reference / model (F)</button>
  <button class="flipmap" title="key M">HDR-FLIP map (M)</button>
  <button class="diffmap" title="key D">difference map (D)</button>
  <label>wipe <input class="wipe" type="range" min="0" max="100" value="100"></label>
  <label>exposure <input class="exposure" type="range" min="-4" max="4" step="0.5"
   value="0"> <span class="ev">0</span> stops</label>
 </div>
 <div class="frame"><img class="base" alt="reference"><img class="top" alt="model"></div>
 <div class="colourbar" hidden><span class="lo">0</span><img class="bar" alt="colour bar">
  <span class="hi">1</span> <span class="what"></span></div>
 <div class="caption"></div>
</div>'''


_STYLE = """
body{font-family:system-ui,sans-serif;margin:1.5em;color:rgb(34,34,34);max-width:1400px}
table{border-collapse:collapse;margin:.6em 0;font-size:13px}
th,td{border:1px solid #ccc;padding:2px 6px;text-align:right}
td.text,th:first-child{text-align:left}
th{cursor:pointer;background:#f0f0f0;user-select:none}
th[aria-sort=ascending]::after{content:" \\25B2"} th[aria-sort=descending]::after{content:" \\25BC"}
.viewer{border:1px solid #bbb;padding:.6em;margin:.8em 0;display:inline-block;outline:none}
.viewer:focus{border-color:#36c}
.frame{position:relative;width:384px;height:384px;background:black}
.frame img{position:absolute;left:0;top:0;width:384px;height:384px;image-rendering:pixelated}
.controls{margin-bottom:.4em} .controls label{margin-right:.8em}
.caption{font-size:13px;margin-top:.3em;min-height:1.2em}
.colourbar{font-size:12px;margin-top:.3em;display:flex;align-items:center;gap:4px}
.colourbar img{width:360px;height:12px;border:1px solid rgb(136,136,136)}
.colourbar[hidden]{display:none}
img.chart{max-width:100%;border:1px solid #ddd;margin:.4em 0}
"""

_SCRIPT = r"""
const errors = [];
window.addEventListener('error', e => errors.push(String(e.message)));
const consoleError = console.error;
console.error = (...a) => { errors.push(a.join(' ')); consoleError(...a); };
const DATA = JSON.parse(document.getElementById('bench-data').textContent);

function sortTable(th) {
  const table = th.closest('table'), body = table.tBodies[0];
  const col = Array.from(th.parentNode.children).indexOf(th);
  const asc = th.getAttribute('aria-sort') !== 'ascending';
  table.querySelectorAll('th').forEach(h => h.removeAttribute('aria-sort'));
  th.setAttribute('aria-sort', asc ? 'ascending' : 'descending');
  const key = tr => {
    const td = tr.children[col];
    if (td.dataset.v === undefined) return td.textContent;
    return td.dataset.v === '' ? NaN : parseFloat(td.dataset.v);
  };
  const rows = Array.from(body.rows);
  rows.sort((a, b) => {
    const x = key(a), y = key(b);
    if (typeof x === 'number' && typeof y === 'number') {
      if (isNaN(x) || isNaN(y)) return isNaN(x) - isNaN(y);  // no figure: last
      return asc ? x - y : y - x;
    }
    return asc ? String(x).localeCompare(y) : String(y).localeCompare(x);
  });
  rows.forEach(r => body.appendChild(r));
}
document.querySelectorAll('table.sortable th').forEach(th =>
  th.addEventListener('click', () => sortTable(th)));

const viewers = [];
let active = null;
function fmt(x, d) {
  if (x === null || x === undefined) return '-';
  return typeof x === 'string' ? x : Number(x).toFixed(d);
}
function setupViewer(el) {
  const mats = DATA.viewer[el.dataset.scene] || {};
  const matSel = el.querySelector('.material'), modSel = el.querySelector('.model');
  const base = el.querySelector('.base'), top = el.querySelector('.top');
  const wipe = el.querySelector('.wipe'), caption = el.querySelector('.caption');
  const exposure = el.querySelector('.exposure'), bar = el.querySelector('.colourbar');
  const v = {el, map: null, base, top, wipe, exposure, bar};
  const MAPS = {flip: ['flip_map', 'HDR-FLIP map', 'flipmap', 'HDR-FLIP, 0 (identical) to 1'],
                diff: ['diff_map', 'difference map', 'diffmap',
                       '|ref - img| x 10, linear radiance, 0 to 1']};
  for (const m of Object.keys(mats)) matSel.add(new Option(m, m));
  function fillModels() {
    const keep = modSel.value;
    modSel.innerHTML = '';
    for (const m of Object.keys((mats[matSel.value] || {}).models || {}))
      modSel.add(new Option(m, m));
    if (keep && Array.from(modSel.options).some(o => o.value === keep)) modSel.value = keep;
  }
  v.cell = () => ((mats[matSel.value] || {}).models || {})[modSel.value];
  v.update = () => {
    const mat = mats[matSel.value], cell = v.cell();
    if (!mat || !cell) { caption.textContent = 'no renders in this scene'; return; }
    base.src = mat.reference;
    const m = v.map && cell[MAPS[v.map][0]] ? MAPS[v.map] : null;
    top.src = m ? cell[m[0]] : cell.render;
    const w = Number(wipe.value), ev = Number(exposure.value);
    top.style.clipPath = 'inset(0 ' + (100 - w) + '% 0 0)';
    const gain = 'brightness(' + Math.pow(2, ev) + ')';  // the tone-mapped renders only
    base.style.filter = gain;
    top.style.filter = m ? 'none' : gain;
    el.querySelector('.ev').textContent = String(ev);
    bar.hidden = !(m && w > 0);
    if (m) { bar.querySelector('.bar').src = DATA.bars[v.map];
             bar.querySelector('.what').textContent = m[3]; }
    const shown = w === 100 ? (m ? m[1] + ' of ' + modSel.value : 'model ' + modSel.value)
      : w === 0 ? 'reference' : 'left: ' + (m ? m[1] : 'model') + ', right: reference';
    el.dataset.shown = w === 100 ? (m ? m[2] : 'model') : w === 0 ? 'reference' : 'wipe';
    caption.textContent = 'showing ' + shown + ' | SNR ' + fmt(cell.snr_object, 1) +
      ' dB object-only, ' + fmt(cell.snr_whole, 1) + ' dB whole-image | HDR-FLIP ' +
      fmt(cell.flip, 3);
  };
  v.flip = () => { wipe.value = Number(wipe.value) === 0 ? 100 : 0; v.update(); };
  v.toggleMap = (kind = 'flip') => { v.map = v.map === kind ? null : kind;
                                      if (Number(wipe.value) === 0) wipe.value = 100;
                                      v.update(); };
  matSel.addEventListener('change', () => { fillModels(); v.update(); });
  modSel.addEventListener('change', v.update);
  wipe.addEventListener('input', v.update);
  exposure.addEventListener('input', v.update);
  el.querySelector('.flip').addEventListener('click', v.flip);
  el.querySelector('.flipmap').addEventListener('click', () => v.toggleMap('flip'));
  el.querySelector('.diffmap').addEventListener('click', () => v.toggleMap('diff'));
  el.addEventListener('focusin', () => { active = v; });
  el.addEventListener('pointerdown', () => { active = v; });
  fillModels();
  v.update();
  viewers.push(v);
}
document.querySelectorAll('.viewer').forEach(setupViewer);
active = viewers[0] || null;
// The keys work whatever has focus (a menu, a slider, a button, a table): a menu's
// type-ahead would otherwise take F, M or D as the first letter of an option.
document.addEventListener('keydown', e => {
  if (!active || e.ctrlKey || e.metaKey || e.altKey) return;
  const k = e.key.toLowerCase();
  if (k === 'f') active.flip();
  else if (k === 'm') active.toggleMap('flip');
  else if (k === 'd') active.toggleMap('diff');
  else return;
  e.preventDefault();
}, true);

// A sort that changes nothing proves nothing: check on the first numeric column whose
// values differ that a click sorts it ascending and a second click descending, the
// rows (not just the arrow) reordered and none lost.
function sortCheck() {
  for (const table of document.querySelectorAll('table.sortable')) {
    const ths = Array.from(table.tHead.rows[0].cells), body = table.tBodies[0];
    for (let col = 0; col < ths.length; col++) {
      const keys = () => Array.from(body.rows, tr => {
        const v = tr.children[col].dataset.v;
        return v === undefined || v === '' ? NaN : parseFloat(v);
      });
      const rows = () => Array.from(body.rows, tr => tr.textContent).join('\n');
      const before = keys();
      if (before.some(isNaN) || new Set(before).size < 2) continue;
      const sorted = before.slice().sort((a, b) => a - b);
      ths[col].click();
      const up = keys(), upRows = rows(), upSort = ths[col].getAttribute('aria-sort');
      ths[col].click();
      const down = keys(), downRows = rows(), downSort = ths[col].getAttribute('aria-sort');
      const same = (a, b) => a.length === b.length && a.every((x, i) => x === b[i]);
      const ascending = upSort === 'ascending' && same(up, sorted);
      const descending = downSort === 'descending' && same(down, sorted.slice().reverse());
      return {column: ths[col].textContent, before, ascending: up, descending: down,
              ok: ascending && descending && upRows !== downRows};
    }
  }
  return null;  // no numeric column with two different values: nothing to check
}

function selftest() {
  const out = {checks: {}, errors};
  out.checks.images_loaded = Array.from(document.images).every(
    i => !i.getAttribute('src') || (i.complete && i.naturalWidth > 0));
  const v = viewers.find(x => x.cell());
  if (v) {
    const key = k => document.dispatchEvent(new KeyboardEvent('keydown', {key: k}));
    active = v;
    out.checks.starts_on_model = v.el.dataset.shown === 'model';
    key('f');
    out.checks.flips_to_reference = v.el.dataset.shown === 'reference' &&
      v.top.style.clipPath.includes('100%');
    key('f');
    out.checks.flips_back = v.el.dataset.shown === 'model';
    key('m');
    out.checks.flip_map = v.el.dataset.shown === 'flipmap' && v.top.src === v.cell().flip_map;
    out.checks.flip_colour_bar = !v.bar.hidden &&
      v.bar.querySelector('.bar').src === DATA.bars.flip;
    key('d');
    out.checks.diff_map = v.el.dataset.shown === 'diffmap' && v.top.src === v.cell().diff_map &&
      v.bar.querySelector('.bar').src === DATA.bars.diff;
    key('d');
    out.checks.map_off = v.el.dataset.shown === 'model' && v.bar.hidden;
    // a key pressed while a menu has focus reaches the viewer, and leaves the menu as it was
    const menu = v.el.querySelector('.model'), chosen = menu.value;
    menu.focus();
    menu.dispatchEvent(new KeyboardEvent('keydown', {key: 'f', bubbles: true,
                                                     cancelable: true}));
    out.checks.key_with_menu_focused = v.el.dataset.shown === 'reference' &&
      menu.value === chosen;
    key('f');
    v.exposure.value = 2; v.exposure.dispatchEvent(new Event('input'));
    out.checks.exposure = v.top.style.filter === 'brightness(4)' &&
      v.base.style.filter === 'brightness(4)';
    v.exposure.value = 0; v.exposure.dispatchEvent(new Event('input'));
    key('m');  // the FLIP map again, half wiped: what the screenshot shows
    v.wipe.value = 50; v.wipe.dispatchEvent(new Event('input'));
    out.checks.wipe = v.el.dataset.shown === 'wipe';
  } else {
    out.checks.viewer = false;
  }
  out.sort = sortCheck();
  out.checks.sorts = out.sort !== null && out.sort.ok;
  out.ok = Object.values(out.checks).every(Boolean) && errors.length === 0;
  document.getElementById('selftest-result').textContent = JSON.stringify(out);
  document.title = 'selftest ' + (out.ok ? 'ok' : 'failed');
}
if (location.hash === '#selftest') window.addEventListener('load', selftest);
"""


def write_html_report(results: dict, out: Path) -> Path:
    """Write ``report.html`` in ``out`` (see the module doc), after ``report.md``.

    Parameters
    ----------
    results : dict
        A bench's results (``results.json``).
    out : Path
        The bench's output folder: its ``work/`` renders and FLIP maps are read, and the
        PNG charts that its ``report.md`` shows are embedded, in that order (not its render
        figures: the viewer shows those renders).

    Returns
    -------
    Path
        The page written.
    """
    out = Path(out)
    md = out / "report.md"
    charts = [out / name for name in  # the render figures: the viewer shows them better
              re.findall(r"\]\(([^)/]+\.png)\)", md.read_text() if md.is_file() else "")
              if not name.startswith("renders-")]
    cfg = results["config"]
    scenes = scenes_of(results)
    body = ["<h1>sparse-brdf bench report</h1>",
            f"<p>Corpora {html.escape(', '.join(cfg['corpora']))} ({html.escape(cfg['split'])}"
            f" split), {cfg['res']}x{cfg['res']}, {cfg['spp']} spp, seed {cfg['seed']}."
            f"{html.escape(seeds_sentence(cfg))} "
            f"SNR in dB: <i>obj</i> = {OBJECT_ONLY}, <i>whole</i> = {WHOLE_IMAGE}; HDR-FLIP "
            "over the object's pixels (0 is identical). Click a column's header to sort; in "
            "a viewer, F flips between reference and model, M shows the HDR-FLIP map and D the "
            "difference map (each with its colour bar), whatever has focus; one slider "
            "wipes, the other sets the display exposure of the tone-mapped renders.</p>"]
    for scene, why in results.get("skipped_scenes", {}).items():
        body.append(f"<p>Skipped scene <code>{html.escape(scene)}</code>: "
                    f"{html.escape(why)}</p>")
    failed = failed_cells(results)
    if failed:
        body += [f"<h2>Failed cells</h2><p>{len(failed)} of {len(results['cells'])} cells "
                 "failed; they are left out of every mean below and run again by the next "
                 "run of this bench.</p>",
                 _table(["material", "model", "error"],
                        [[_cell(c["material"], ""), _cell(c["model"], ""),
                          _cell(c["error"], "")] for c in failed])]
    ramp = np.tile(np.linspace(0, 1, 256), (8, 1))  # the maps' colour bars, 0 to 1
    data: dict = {"viewer": {}, "bars": {"flip": _image_uri(scalar=ramp, cmap="magma"),
                                         "diff": _image_uri(scalar=ramp, cmap="jet")}}
    for i, scene in enumerate(scenes):
        data["viewer"][scene] = viewer_data(results, out, scene)
        body += [f"<h2>Scene <code>{html.escape(scene)}</code></h2>", _noise_floor(results, scene),
                 "<h3>Models</h3>", _model_table(results, scene), "<h3>Renders</h3>",
                 _viewer(scene, i), "<h3>Per material</h3>", _material_table(results, scene)]
    if not scenes:
        body += ["<h2>BRDF-space metrics (no renders)</h2>", _model_table(results, None)]
    body += _stability(results)
    if charts:
        body.append("<h2>Charts</h2>")
        body += [f'<p>{html.escape(p.name)}<br><img class="chart" alt="{html.escape(p.stem)}" '
                 f'src="{_png_uri(p)}"></p>' for p in charts if p.is_file()]
    body += ["<h2>Environment and provenance</h2>",
             _table(["what", "value"], [[_cell(w, ""), _cell(v, "")]
                                        for w, v in provenance_rows(results)])]
    payload = json.dumps(data, allow_nan=False).replace("</", "<\\/")
    page = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; "
            "img-src data:; style-src 'unsafe-inline'; script-src 'unsafe-inline'\">"
            f"<title>sparse-brdf bench report</title><style>{_STYLE}</style></head><body>"
            + "\n".join(body)
            + '\n<pre id="selftest-result"></pre>'
            + f'<script type="application/json" id="bench-data">{payload}</script>'
            + f"<script>{_SCRIPT}</script></body></html>\n")
    path = out / "report.html"
    with atomic_write(path, "w") as f:
        f.write(page)
    return path
