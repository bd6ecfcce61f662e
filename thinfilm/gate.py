"""The regression gate of ``thinfilm benchmark --baseline OLD/results.json``.

Every metric of every (case, kind, method) row of a run is compared with the same row of an
earlier run. A value is a regression when it is worse than the baseline by more than the
tolerance of its metric, ``max(absolute, relative × |baseline|)``:

==========================  ===============  ========  ========================================
metric                      absolute         relative  statistics compared
==========================  ===============  ========  ========================================
``normal_error_deg``        0.1°             10 %      mean, median, p95; max: twice the tolerance
``zenith_error_deg``        0.1°             10 %      as above
``thickness_error_nm``      1 nm             10 %      as above
``delta_e_ab``              0.1              10 %      as above
``delta_e_2000``            0.1              10 %      as above
``spectral_rmse``           0.001 (0.1 %)    10 %      as above
``film_ior_error``          0.002            10 %      the value
``coverage``                0.01             0 %       the value; lower is worse
==========================  ===============  ========  ========================================

Higher is worse for every metric but coverage. A metric that had a value and has none now is a
regression. A row of the baseline that is missing from the run, or that failed in the run but
not in the baseline, is a regression (drop a scene or method on purpose: take a new baseline).
Rows that failed in the baseline are not compared; rows new in the run are listed, not judged.
The whole pipeline is deterministic (same spec and seed, same bytes), so the tolerances are for
changes of the code, not for noise between runs.

Examples
--------
>>> row = {"scene": "a", "kind": "rgb", "method": "m", "metrics": {"normal_error_deg": {"mean": 1.0}}}
>>> worse = dict(row, metrics={"normal_error_deg": {"mean": 1.2}})
>>> [f["metric"] for f in compare({"rows": [worse]}, {"rows": [row]})["regressions"]]
['normal_error_deg.mean']
>>> compare({"rows": [row]}, {"rows": [worse]})["regressions"]
[]
"""

from __future__ import annotations

from pathlib import Path

from thinfilm.core.errors import UserError

__all__ = ["TOLERANCES", "STATS", "MAX_FACTOR", "read_baseline", "compare", "gate_text", "gate_markdown"]

#: metric → (absolute, relative) tolerance on how much worse a value may get
TOLERANCES = {
    "normal_error_deg": (0.1, 0.10),
    "zenith_error_deg": (0.1, 0.10),
    "thickness_error_nm": (1.0, 0.10),
    "delta_e_ab": (0.1, 0.10),
    "delta_e_2000": (0.1, 0.10),
    "spectral_rmse": (0.001, 0.10),
    "film_ior_error": (0.002, 0.10),
    "coverage": (0.01, 0.0),
}
#: statistics of the per-pixel metrics that are compared
STATS = ("mean", "median", "p95", "max")
#: the tolerance of ``max`` (one pixel) is this many times the metric's
MAX_FACTOR = 2.0


def read_baseline(path) -> dict:
    """An earlier ``results.json`` (or the folder holding it). One-line errors."""
    from thinfilm.core.io import read_json

    p = Path(path).expanduser()
    if p.is_dir():
        p = p / "results.json"
    if not p.is_file():
        raise UserError(f"--baseline {path}: results.json not found")
    data = read_json(p)
    if not isinstance(data, dict) or not isinstance(data.get("rows"), list):
        raise UserError(f"--baseline {p}: not a thinfilm benchmark results.json (no 'rows')")
    return data


def _key(row) -> tuple:
    # results of format 1 named the case 'preset'
    return (row.get("scene", row.get("preset")), row.get("kind"), row.get("method"))


def _number(v):
    return v if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def _values(row) -> dict:
    """``{"metric.stat": value}`` of a row (``coverage``, ``film_ior_error`` as themselves)."""
    out = {}
    metrics = row.get("metrics") or {}
    for metric in TOLERANCES:
        if metric == "coverage":
            out["coverage"] = _number(row.get("coverage"))
        elif metric == "film_ior_error":
            out["film_ior_error"] = _number(metrics.get("film_ior_error"))
        else:
            stats = metrics.get(metric) or {}
            for stat in STATS:
                out[f"{metric}.{stat}"] = _number(stats.get(stat)) if isinstance(stats, dict) else None
    return out


def compare(results: dict, baseline: dict) -> dict:
    """Compare run ``results`` with ``baseline`` (both ``results.json`` contents).

    Returns
    -------
    dict
        ``regressions``: one dict per finding (``scene``, ``kind``, ``method``, ``metric``,
        ``baseline``, ``now``, ``allowed`` (the worst value still accepted) or ``problem``);
        ``compared`` (rows compared), ``new`` (rows not in the baseline), ``skipped`` (rows
        that failed in the baseline) and ``notes`` (differences of settings).
    """
    now = {_key(r): r for r in results.get("rows", [])}
    base = {_key(r): r for r in baseline.get("rows", [])}
    regressions, skipped, compared = [], [], 0
    for key, b in base.items():
        scene, kind, method = key
        who = {"scene": scene, "kind": kind, "method": method}
        if "error" in b or b.get("status") == "failed":
            skipped.append(who)
            continue
        r = now.get(key)
        if r is None:
            regressions.append(dict(who, metric="-", problem="missing from this run"))
            continue
        if "error" in r or r.get("status") == "failed":
            regressions.append(dict(who, metric="-", problem=f"failed: {r.get('error', '?')}"))
            continue
        compared += 1
        vb, vn = _values(b), _values(r)
        for name, old in vb.items():
            if old is None:
                continue
            new = vn.get(name)
            metric, _, stat = name.partition(".")
            absolute, relative = TOLERANCES[metric]
            factor = MAX_FACTOR if stat == "max" else 1.0
            tol = factor * max(absolute, relative * abs(old))
            if new is None:
                regressions.append(dict(who, metric=name, baseline=old, now=None, problem="no value"))
            elif metric == "coverage":
                if new < old - tol:
                    regressions.append(dict(who, metric=name, baseline=old, now=new, allowed=old - tol))
            elif new > old + tol:
                regressions.append(dict(who, metric=name, baseline=old, now=new, allowed=old + tol))
    new_rows = [{"scene": k[0], "kind": k[1], "method": k[2]} for k in now if k not in base]
    notes = []
    for setting in ("quick", "resolution"):
        if results.get(setting) != baseline.get(setting):
            notes.append(f"{setting}: baseline {baseline.get(setting)!r}, this run {results.get(setting)!r}")
    s_now, s_base = (results.get("suite") or {}).get("name"), (baseline.get("suite") or {}).get("name")
    if s_now != s_base:
        notes.append(f"suite: baseline {s_base!r}, this run {s_now!r}")
    return {"regressions": regressions, "compared": compared, "new": new_rows, "skipped": skipped,
            "notes": notes, "tolerances": {k: list(v) for k, v in TOLERANCES.items()}}


def _g(v) -> str:
    return "—" if v is None else f"{v:.4g}"


def _table(gate) -> list:
    rows = [("scene", "kind", "method", "metric", "baseline", "now", "allowed")]
    for f in gate["regressions"]:
        rows.append((str(f["scene"]), str(f["kind"]), str(f["method"]), f["metric"], _g(f.get("baseline")),
                     f.get("problem") or _g(f.get("now")), _g(f.get("allowed"))))
    return rows


def gate_text(gate: dict, baseline_path="baseline") -> str:
    """What the command prints: a summary line, then the table of regressions."""
    n = len(gate["regressions"])
    lines = [f"regression gate against {baseline_path}: {gate['compared']} rows compared, "
             f"{n} regression{'s' if n != 1 else ''}"
             + (f", {len(gate['new'])} new rows" if gate["new"] else "")
             + (f", {len(gate['skipped'])} rows failed in the baseline" if gate["skipped"] else "")]
    lines += [f"  note: settings differ: {note}" for note in gate["notes"]]
    if n:
        rows = _table(gate)
        widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
        lines += ["  " + "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
    return "\n".join(lines)


def gate_markdown(gate: dict) -> list:
    """The report's section on the comparison with the baseline."""
    n = len(gate["regressions"])
    lines = ["## Regression gate", "",
             f"{gate['compared']} rows compared with the baseline: **{n} regression{'s' if n != 1 else ''}**"
             + ("; new rows: " + ", ".join(f"{r['scene']}/{r['kind']}/{r['method']}" for r in gate["new"])
                if gate["new"] else "") + ".", ""]
    lines += [f"- settings differ: {note}" for note in gate["notes"]]
    if n:
        rows = _table(gate)
        lines += ["| " + " | ".join(rows[0]) + " |", "|" + "---|" * len(rows[0])]
        lines += ["| " + " | ".join(c.replace("|", "/") for c in r) + " |" for r in rows[1:]]
    lines.append("")
    return lines
