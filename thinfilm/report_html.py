"""``report.html``: the benchmark report for the browser (:func:`render_report_html`).

One HTML file beside ``report.md`` in a benchmark's output folder. Its script and style are
inline; the figures are the PNG files of the task folders, linked by paths relative to the
report, so the folder can be moved, archived or served as it is. Nothing comes from the
network: the page's Content-Security-Policy loads images from the folder only and runs only
the page's own script (by its hash).

- **Leaderboards** per kind with the columns of ``report.md``'s (efficiency: the Cramér-Rao
  bound's RMS over the error's), for all scenes or for the scene the filter picks.
- **Tasks**: one row per task (scene × method, the ground truth too).
- Every table sorts by any column (click its header, again to reverse; cells without a
  value stay last); a column of ``mean / p95`` sorts by the mean.
- **Filters** by scene and by method apply to the leaderboards and the tasks.
- **A view per task** (``report.html#task-N``, opened from the tasks table): its metrics, the
  dataset's preview, captured versus re-rendered with the ΔE*ab map, the normal, thickness and
  error maps, the bound maps, or the failure and its traceback. The view works without the
  script (CSS ``:target``).

Every string that comes from a suite, a scene, a method or an error is HTML-escaped. What
differs from run to run (times, where it ran, what was resumed) is in elements of class
``timing``.
"""

from __future__ import annotations

import base64
import hashlib
import html
import math
import numbers
from pathlib import Path
from urllib.parse import quote

__all__ = ["SCRIPT", "STYLE", "TASK_FIGURES", "render_report_html"]

#: the figures a task view shows, in order: (file in the task's evaluation folder, caption);
#: ``None`` is the dataset's ``preview.png``
TASK_FIGURES = (
    (None, "the dataset's captures (preview)"),
    ("appearance.png", "captured (s-polarized) | re-rendered from the estimate | ΔE*ab"),
    ("normals.png", "normals: truth | estimate | angular error"),
    ("thickness.png", "thickness: truth | estimate | error"),
    ("errors.png", "error maps: zenith, ΔE00, spectral RMSE"),
    ("bound.png", "Cramér-Rao bound (normal, thickness) and each error over its bound"),
)

STYLE = """
:root { --fg: #1d2228; --muted: #5b6570; --line: #d5dae0; --head: #eef1f4; --accent: #1f5fa8; }
* { box-sizing: border-box; }
body { margin: 0; font: 14px/1.45 system-ui, -apple-system, "Segoe UI", sans-serif; color: var(--fg); }
header, main { padding: 0 24px; }
header { border-bottom: 1px solid var(--line); padding-bottom: 8px; }
h1 { font-size: 22px; margin: 16px 0 6px; }
h2 { font-size: 18px; margin: 22px 0 8px; }
h3 { font-size: 15px; margin: 16px 0 6px; }
p { margin: 4px 0; }
.muted { color: var(--muted); }
[hidden] { display: none !important; }
a { color: var(--accent); }
table { border-collapse: collapse; margin: 6px 0 12px; font-variant-numeric: tabular-nums; }
th, td { border: 1px solid var(--line); padding: 3px 8px; text-align: right; white-space: nowrap; }
th { background: var(--head); font-weight: 600; white-space: normal; vertical-align: bottom; min-width: 4em; }
td.t, th.t { text-align: left; }
table.sortable th { cursor: pointer; user-select: none; }
table.sortable th::after { content: " \\2195"; color: #9aa3ad; }
table.sortable th[aria-sort="ascending"]::after { content: " \\2191"; color: var(--fg); }
table.sortable th[aria-sort="descending"]::after { content: " \\2193"; color: var(--fg); }
tbody tr:nth-child(even) { background: #f8f9fb; }
tr.failed td { color: #a1262b; }
.scroll { overflow-x: auto; }
nav.filters { position: sticky; top: 0; z-index: 2; background: #fff; border-bottom: 1px solid var(--line);
  padding: 8px 0; display: flex; gap: 18px; align-items: center; flex-wrap: wrap; }
nav.filters select { font: inherit; padding: 2px 4px; }
.task { display: none; border: 1px solid var(--line); border-radius: 6px; padding: 4px 16px 12px;
  margin: 16px 0; background: #fbfcfd; }
.task:target { display: block; }
.task nav { float: right; margin-top: 14px; display: flex; gap: 14px; }
.figures { display: grid; grid-template-columns: repeat(auto-fill, minmax(520px, 1fr)); gap: 10px 16px; }
figure { margin: 0; }
figure img { max-width: 100%; height: auto; border: 1px solid var(--line); background: #fff; }
figure img.preview { image-rendering: pixelated; width: 256px; max-width: 100%; }
figcaption { color: var(--muted); font-size: 12px; }
pre { background: #f3f4f6; padding: 8px; overflow-x: auto; }
"""

SCRIPT = """
(function () {
  "use strict";
  function each(list, f) { Array.prototype.forEach.call(list, f); }
  function cellValue(row, col) {
    var cell = row.cells[col];
    if (!cell) { return ""; }
    return cell.hasAttribute("data-v") ? cell.getAttribute("data-v") : cell.textContent.trim();
  }
  // Sort a table's body by one column: ascending first, then descending; rows without a
  // value last either way; ties keep their order (so sorts by several columns compose).
  function sortTable(table, col, th) {
    var ascending = th.getAttribute("aria-sort") !== "ascending";
    each(th.parentNode.cells, function (h) { h.removeAttribute("aria-sort"); });
    th.setAttribute("aria-sort", ascending ? "ascending" : "descending");
    var numeric = th.getAttribute("data-type") === "num";
    var body = table.tBodies[0];
    var keyed = Array.prototype.map.call(body.rows, function (row, i) {
      var v = cellValue(row, col);
      var key = numeric ? parseFloat(v) : v.toLowerCase();
      return { row: row, i: i, key: key, missing: v === "" || (numeric && isNaN(key)) };
    });
    keyed.sort(function (a, b) {
      if (a.missing !== b.missing) { return a.missing ? 1 : -1; }
      var c = 0;
      if (!a.missing) { c = numeric ? a.key - b.key : a.key.localeCompare(b.key); }
      return (ascending ? c : -c) || a.i - b.i;
    });
    keyed.forEach(function (k) { body.appendChild(k.row); });
  }
  each(document.querySelectorAll("table.sortable"), function (table) {
    each(table.tHead.rows[0].cells, function (th, col) {
      th.tabIndex = 0;
      th.title = (th.title ? th.title + "; " : "") + "click to sort";
      th.addEventListener("click", function () { sortTable(table, col, th); });
      th.addEventListener("keydown", function (e) {
        if (e.key === "Enter" || e.key === " ") { e.preventDefault(); sortTable(table, col, th); }
      });
    });
  });
  // Filters: the leaderboard of the chosen scene (or of all), the rows of the chosen method.
  var scene = document.getElementById("f-scene");
  var method = document.getElementById("f-method");
  var count = document.getElementById("f-count");
  function apply() {
    var s = scene.value, m = method.value;
    each(document.querySelectorAll("section.kind"), function (kind) {
      var shown = 0;
      each(kind.querySelectorAll(".board"), function (board) {
        board.hidden = board.getAttribute("data-scene") !== s;
        if (board.hidden) { return; }
        each(board.querySelectorAll("tbody tr"), function (row) {
          row.hidden = m !== "" && row.getAttribute("data-method") !== m;
          if (!row.hidden) { shown += 1; }
        });
      });
      kind.querySelector(".empty").hidden = shown > 0;
    });
    var n = 0, total = 0;
    each(document.querySelectorAll("#task-table tbody tr"), function (row) {
      var on = (s === "" || row.getAttribute("data-scene") === s) &&
               (m === "" || row.getAttribute("data-method") === m);
      row.hidden = !on;
      total += 1;
      if (on) { n += 1; }
    });
    count.textContent = n + " of " + total + " tasks shown";
  }
  scene.addEventListener("change", apply);
  method.addEventListener("change", apply);
  apply();
})();
"""


# -- formatting ------------------------------------------------------------------------------------

def _e(text) -> str:
    """``text`` HTML-escaped, quotes too (safe in text and in attribute values)."""
    return html.escape("" if text is None else str(text), quote=True)


def _url(path: str) -> str:
    """A relative path as an escaped URL (each segment percent-encoded)."""
    return _e(quote(str(path), safe="/"))


def _number(value, scale=1.0):
    """``value * scale`` as a float, None unless ``value`` is a finite number."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        return None
    return float(value) * scale


def _fmt(value, digits=2, scale=1.0) -> str:
    if isinstance(value, str):
        return value
    v = _number(value, scale)
    return "—" if v is None else f"{v:.{digits}f}"


def _pct(value) -> str:
    v = _number(value)
    return "—" if v is None else f"{100 * v:.0f} %"


def _td(text, sort=None, timing=False) -> str:
    """A cell showing ``text`` (escaped), sorted by the number ``sort`` (None: last);
    ``timing``: a time, which differs from run to run (class ``timing``)."""
    v = _number(sort)
    cls = ' class="timing"' if timing else ""
    return f'<td{cls} data-v="{"" if v is None else repr(v)}">{_e(text)}</td>'


def _tt(text) -> str:
    """A text cell (sorted by its text)."""
    return f'<td class="t">{_e(text)}</td>'


def _th(text, kind="num", title=None) -> str:
    """A header of a sortable column: ``kind`` "num" (by each cell's ``data-v``) or "text"."""
    cls = ' class="t"' if kind == "text" else ""
    t = f' title="{_e(title)}"' if title else ""
    return f'<th data-type="{kind}"{cls}{t}>{_e(text)}</th>'


def _metric(row, key, stat="mean"):
    m = (row.get("metrics") or {}).get(key)
    if isinstance(m, dict):
        return m.get(stat)
    return m


# -- leaderboards ----------------------------------------------------------------------------------

_BOARD_HEAD = [("rank", "num", None), ("method", "text", None), ("role", "text", None), ("source", "text", None),
               ("scenes (failed)", "num", "sorts by the number of failed scenes"),
               ("normal err. mean / p95 (°)", "num", "sorts by the mean"),
               ("thickness err. mean (nm)", "num", None), ("ΔE*ab", "num", None), ("ΔE00", "num", None),
               ("spectral RMSE (%)", "num", None), ("n2 err.", "num", None),
               ("efficiency normal / thickness", "num", "Cramér-Rao bound RMS / error RMS; sorts by normal"),
               ("coverage", "num", None), ("reconstruct (s)", "num", None)]


def _board_table(board, kind, scene) -> str:
    head = "".join(_th(*h) for h in _BOARD_HEAD)
    body = []
    for i, e in enumerate(board, 1):
        cells = [
            _td(i, i), _tt(e["method"]), _tt(e.get("role")), _tt(e.get("source") or "—"),
            _td(f"{e['cases']} ({e['failed']})", e["failed"]),
            _td(f"{_fmt(e['normal_error_deg'])} / {_fmt(e['normal_error_p95'])}", e["normal_error_deg"]),
            _td(_fmt(e["thickness_error_nm"], 1), e["thickness_error_nm"]),
            _td(_fmt(e["delta_e_ab"]), e["delta_e_ab"]), _td(_fmt(e["delta_e_2000"]), e["delta_e_2000"]),
            _td(_fmt(e["spectral_rmse"], scale=100.0), _number(e["spectral_rmse"], 100.0)),
            _td(_fmt(e["film_ior_error"], 3), e["film_ior_error"]),
            _td(f"{_fmt(e['efficiency_normal'])} / {_fmt(e['efficiency_thickness'])}", e["efficiency_normal"]),
            _td(_pct(e["coverage"]), e["coverage"]), _td(_fmt(e["reconstruct_s"], 1), e["reconstruct_s"], True),
        ]
        body.append(f'<tr data-method="{_e(e["method"])}">{"".join(cells)}</tr>')
    return (f'<div class="board scroll" data-scene="{_e(scene)}"{"" if scene == "" else " hidden"}>'
            f'<table class="sortable" data-kind="{_e(kind)}"><thead><tr>{head}</tr></thead>'
            f'<tbody>{"".join(body)}</tbody></table></div>')


# -- tasks -----------------------------------------------------------------------------------------

_TASK_HEAD = [("scene", "text", None), ("kind", "text", None), ("method", "text", "opens the task's view"),
              ("role", "text", None), ("status", "text", None),
              ("normal err. mean / p95 (°)", "num", "sorts by the mean"), ("zenith err. mean (°)", "num", None),
              ("thickness err. mean / p95 (nm)", "num", "sorts by the mean"),
              ("n2 est. (err.)", "num", "sorts by the error"),
              ("ΔE*ab mean / p95", "num", "sorts by the mean"), ("ΔE00 mean", "num", None),
              ("spectral RMSE mean (%)", "num", None),
              ("efficiency normal / thickness", "num", "Cramér-Rao bound RMS / error RMS; sorts by normal"),
              ("coverage", "num", None), ("reconstruct (s)", "num", None)]


def _kind_label(kind) -> str:
    return "ground truth" if kind == "-" else str(kind)


def _n2(row) -> str:
    fi = row.get("film_ior_estimated")
    est = f"{fi:.3f}" if _number(fi) is not None else ("—" if fi is None else str(fi))
    return f"{est} ({_fmt(_metric(row, 'film_ior_error'), 3)})"


def _task_row(i, r) -> str:
    failed = "error" in r

    def m(key, stat="mean"):
        return _metric(r, key, stat)

    cells = [
        _tt(r.get("scene")), _tt(_kind_label(r.get("kind"))),
        f'<td class="t"><a href="#task-{i}">{_e(r.get("method"))}</a></td>', _tt(r.get("role")),
        _tt("failed" if failed else "ok"),
        _td(f"{_fmt(m('normal_error_deg'))} / {_fmt(m('normal_error_deg', 'p95'))}", m("normal_error_deg")),
        _td(_fmt(m("zenith_error_deg")), m("zenith_error_deg")),
        _td(f"{_fmt(m('thickness_error_nm'), 1)} / {_fmt(m('thickness_error_nm', 'p95'), 1)}",
            m("thickness_error_nm")),
        _td("—" if failed else _n2(r), m("film_ior_error")),
        _td(f"{_fmt(m('delta_e_ab'))} / {_fmt(m('delta_e_ab', 'p95'))}", m("delta_e_ab")),
        _td(_fmt(m("delta_e_2000")), m("delta_e_2000")),
        _td(_fmt(m("spectral_rmse"), scale=100.0), _number(m("spectral_rmse"), 100.0)),
        _td(f"{_fmt(m('efficiency_normal'))} / {_fmt(m('efficiency_thickness'))}", m("efficiency_normal")),
        _td(_pct(r.get("coverage")), r.get("coverage")),
        _td("—" if failed else _fmt(r.get("reconstruct_s"), 1), None if failed else r.get("reconstruct_s"), True),
    ]
    return (f'<tr id="row-{i}" class="{"failed" if failed else "ok"}" data-task="{i}" '
            f'data-scene="{_e(r.get("scene"))}" data-method="{_e(r.get("method"))}">{"".join(cells)}</tr>')


def _figures(r, scene, root) -> list:
    """``[(relative path, caption)]`` of the figures of task row ``r`` that exist under
    ``root`` (when None: those the evaluation writes)."""
    if "error" in r or r.get("figures") is False:
        return []
    out = []
    for name, caption in TASK_FIGURES:
        if name is None:
            if scene and scene.get("dataset"):
                out.append((f"{scene['dataset']}/preview.png", caption))
            continue
        if r.get("kind") == "-" and name in ("normals.png", "thickness.png"):
            continue  # the truth beside itself
        if root is None and name == "bound.png" and _metric(r, "crlb_normal_deg", "rms") is None:
            continue
        out.append((f"{r['evaluation']}/{name}", caption))
    if root is not None:
        out = [(p, c) for p, c in out if (Path(root) / p).is_file()]
    return out


#: the order of the metrics in a task's view (any other after them, by name)
_METRIC_ORDER = ("normal_error_deg", "zenith_error_deg", "thickness_error_nm", "delta_e_ab", "delta_e_2000",
                 "spectral_rmse", "crlb_normal_deg", "crlb_thickness_nm", "film_ior_error", "efficiency_normal",
                 "efficiency_thickness")


def _metrics_table(r) -> str:
    metrics = r.get("metrics") or {}
    stats = ("mean", "median", "p95", "max", "rms")
    rows, scalars = [], []
    order = {k: i for i, k in enumerate(_METRIC_ORDER)}
    for key in sorted(metrics, key=lambda k: (order.get(k, len(order)), k)):  # the same, resumed or not
        value = metrics[key]
        if isinstance(value, dict):
            cells = "".join(f"<td>{_e(_fmt(value.get(s), 3))}</td>" for s in stats)
            rows.append(f'<tr><td class="t">{_e(key)}</td>{cells}</tr>')
        else:
            scalars.append(f"{_e(key)} {_e(_fmt(value, 3))}")
    timing = (f"reconstruct {_fmt(r.get('reconstruct_s'), 2)} s, evaluate {_fmt(r.get('evaluate_s'), 2)} s"
              + (" (resumed from an earlier run)" if r.get("resumed") else ""))
    extra = [f"coverage {_e(_pct(r.get('coverage')))}", f"n2 estimated {_e(_n2(r))}"]
    head = "".join(f"<th>{s}</th>" for s in stats)
    table = (f'<div class="scroll"><table><thead><tr><th class="t">metric</th>{head}</tr></thead>'
             f'<tbody>{"".join(rows)}</tbody></table></div>') if rows else ""
    return f'<p>{"; ".join(extra + scalars)}; <span class="timing">{_e(timing)}</span>.</p>{table}'


def _task_view(i, r, n, scene, root) -> str:
    title = f"{r.get('scene')} — {r.get('method')}"
    sub = (f"{_kind_label(r.get('kind'))}, role {r.get('role')}, source {r.get('source') or '—'}; "
           f"task folder {r.get('task')}")
    nav = [f'<a href="#task-{i - 1}">previous</a>' if i > 0 else "",
           f'<a href="#task-{i + 1}">next</a>' if i + 1 < n else "", '<a href="#">close</a>']
    parts = [f'<article class="task" id="task-{i}" data-scene="{_e(r.get("scene"))}" '
             f'data-method="{_e(r.get("method"))}"><nav>{"".join(nav)}</nav>',
             f"<h2>{_e(title)}</h2>", f'<p class="muted">{_e(sub)}</p>']
    links = [(r.get("estimate"), "estimate"), (r.get("evaluation"), "evaluation")]
    if "error" in r:
        parts += [f'<p><b>failed</b>: {_e(r["error"])}</p>', f"<pre>{_e((r.get('traceback') or '').rstrip())}</pre>"]
    else:
        parts.append(_metrics_table(r))
        figures = _figures(r, scene, root)
        if figures:
            figs = []
            for path, caption in figures:
                cls = ' class="preview"' if caption == TASK_FIGURES[0][1] else ""
                figs.append(f'<figure><img{cls} src="{_url(path)}" alt="{_e(caption)}" loading="lazy">'
                            f"<figcaption>{_e(caption)}</figcaption></figure>")
            parts.append(f'<div class="figures">{"".join(figs)}</div>')
        else:
            parts.append('<p class="muted">No figures (the run was made with --no-figures).</p>')
    parts.append("<p>" + " · ".join(f'<a href="{_url(p)}/">{_e(label)}/</a>' for p, label in links if p) + "</p>")
    parts.append("</article>")
    return "".join(parts)


# -- the page --------------------------------------------------------------------------------------

def _csp_hash(text: str) -> str:
    return "'sha256-" + base64.b64encode(hashlib.sha256(text.encode("utf-8")).digest()).decode("ascii") + "'"


def _summary(results) -> list:
    suite = results.get("suite") or {}
    ex = results.get("execution") or {}
    res = (f"{results['resolution']} px" if results.get("resolution")
           else "capped (quick run)" if results.get("quick") else "each scene's own size")
    where = {"in-process": "in one process",
             "local-cluster": f"on a local Dask cluster of {ex.get('workers')} workers",
             "scheduler": f"on a Dask cluster of {ex.get('workers')} workers"}.get(ex.get("mode"), "")
    total = _number((results.get("timings_s") or {}).get("total"))
    lines = [f"<p>Suite <b>{_e(suite.get('name', '?'))}</b>"
             + (f": {_e(suite['description'])}" if suite.get("description") else "") + ".</p>",
             f"<p>{'Quick run' if results.get('quick') else 'Full run'}: images {_e(res)}, "
             f'<span class="timing">total wall time {_e(_fmt(total, 0))} s {_e(where)}'
             + (f" ({_e(ex.get('tasks_resumed'))} tasks resumed)" if ex.get("tasks_resumed") else "") + "</span>.</p>",
             '<p class="muted">Every estimate is re-rendered through the thinfilm BSDF with the dataset\'s rig '
             "and compared with the captures (ΔE*ab, ΔE00, spectral RMSE); errors are over the object mask "
             "where the estimate is valid, <i>coverage</i> is that fraction of the object; the ground truth "
             "scored against the noisy captures is the noise floor. The paper's figures beside ours and the "
             'timings: <a href="report.md">report.md</a>; every row: <a href="results.json">results.json</a>.</p>']
    return lines


def _gate(gate) -> list:
    if gate is None:
        return []
    regs = gate.get("regressions") or []
    out = ['<section id="gate"><h2>Regression gate</h2>',
           f"<p>{_e(gate.get('compared'))} rows compared with the baseline: <b>{len(regs)} regression"
           f"{'s' if len(regs) != 1 else ''}</b>.</p>"]
    out += [f"<p>settings differ: {_e(note)}</p>" for note in gate.get("notes") or []]
    if regs:
        head = "".join(f'<th class="t">{h}</th>' for h in ("scene", "kind", "method", "metric", "baseline", "now",
                                                            "allowed or problem"))
        body = "".join("<tr>" + "".join(_tt(x) for x in (
            f.get("scene"), f.get("kind"), f.get("method"), f.get("metric"), _fmt(f.get("baseline"), 3),
            _fmt(f.get("now"), 3), f.get("problem") or _fmt(f.get("allowed"), 3))) + "</tr>" for f in regs)
        out.append(f'<div class="scroll"><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>')
    out.append("</section>")
    return out


def render_report_html(results: dict, boards: dict, root=None) -> str:
    """The text of ``report.html``.

    Parameters
    ----------
    results : dict
        The benchmark's results (the ``results.json`` content).
    boards : dict
        ``{kind: {scene: leaderboard}}``, scene ``""`` for all scenes; each leaderboard is a
        list of the entries of :func:`thinfilm.benchmark.leaderboard`, ranked.
    root : path, optional
        The folder the report is written into: only the figures that exist there are shown.
        None: the figures an evaluation writes.
    """
    rows = results.get("rows") or []
    scenes = {sc.get("id"): sc for sc in results.get("scenes") or []}
    scene_ids = list(dict.fromkeys([*scenes, *(r.get("scene") for r in rows)]))
    method_names = list(dict.fromkeys(r.get("method") for r in rows))
    style, script = STYLE, SCRIPT
    csp = (f"default-src 'none'; img-src 'self' file: data:; style-src {_csp_hash(style)}; "
           f"script-src {_csp_hash(script)}; base-uri 'none'; form-action 'none'")
    suite = (results.get("suite") or {}).get("name", "?")
    out = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
           f'<meta http-equiv="Content-Security-Policy" content="{_e(csp)}">',
           '<meta name="viewport" content="width=device-width, initial-scale=1">',
           '<link rel="icon" href="data:,">',
           f"<title>thinfilm benchmark: {_e(suite)}</title>", f"<style>{style}</style></head><body>",
           "<header><h1>thinfilm benchmark report</h1>", *_summary(results), "</header><main>"]
    out.append('<section id="task-views">')
    out += [_task_view(i, r, len(rows), scenes.get(r.get("scene")), root) for i, r in enumerate(rows)]
    out.append("</section>")

    opts_s = "".join(f'<option value="{_e(s)}">{_e(s)}</option>' for s in scene_ids)
    opts_m = "".join(f'<option value="{_e(m)}">{_e(m)}</option>' for m in method_names)
    out.append('<nav class="filters"><label>Scene <select id="f-scene"><option value="">all scenes</option>'
               f'{opts_s}</select></label><label>Method <select id="f-method"><option value="">all methods</option>'
               f'{opts_m}</select></label><output id="f-count"></output></nav>')
    if results.get("missing_kinds"):
        out.append("<p><b>Not benchmarked</b> (not available in this version): "
                   + "; ".join(f"{_e(k)}: {_e(v)}" for k, v in results["missing_kinds"].items()) + ".</p>")
    out += _gate(results.get("gate"))

    out += ['<section id="leaderboards"><h2>Leaderboards</h2>',
            '<p class="muted">Methods ranked by the number of failed scenes, then the mean normal error, then '
            "the mean ΔE*ab; each figure is the mean over the scenes the method completed of that scene's mean "
            "(p95: of its 95th percentile). <i>Efficiency</i> is the per-pixel Cramér-Rao bound's RMS over the "
            "error's RMS on the pixels of true zenith 15-75° (1: an efficient unbiased estimator; above 1 only "
            "with priors or bias). With a scene chosen, the ranking is on that scene alone.</p>"]
    for kind in ("rgb", "spectral"):
        per = boards.get(kind) or {}
        if not per.get(""):
            continue
        out.append(f'<section class="kind" id="board-{_e(kind)}"><h3>{_e(kind)}</h3>')
        out += [_board_table(board, kind, scene) for scene, board in per.items() if board]
        out.append(f'<p class="empty muted" hidden>No {_e(kind)} task matches the filters.</p></section>')
    out.append("</section>")

    head = "".join(_th(*h) for h in _TASK_HEAD)
    out += ['<section id="tasks"><h2>Tasks</h2>',
            '<p class="muted">One row per scene and method (the ground truth too); a method opens the task\'s '
            'view: metrics, captures, re-render, error maps and the bound.</p>',
            f'<div class="scroll"><table class="sortable" id="task-table"><thead><tr>{head}</tr></thead><tbody>',
            *[_task_row(i, r) for i, r in enumerate(rows)], "</tbody></table></div></section>"]
    out += ["</main>", f"<script>{script}</script>", "</body></html>", ""]
    return "\n".join(out)
