"""``thinfilm benchmark``: every scene of a suite × every method that applies, scored, at any scale.

::

    thinfilm benchmark [--suite NAME|FILE] [--quick] [--methods a,b,...] [--resolution N]
                       [--resume] [--baseline OLD/results.json] [--no-figures]
                       [--workers N | --scheduler ADDRESS] --out DIR

A *suite* (:mod:`thinfilm.suites`) lists scenes (a preset or a spec file, overrides, seeds,
resolution, the reconstruction kinds that apply) and optionally methods; the default suite,
``presets``, is the three preset objects. Each (scene, seed) is one *case*: a dataset is
generated for it once, then every selected method of each kind that applies reconstructs it
and the estimate is re-rendered and scored (:mod:`thinfilm.evaluation`). The ground truth
itself is scored too: its ΔE is the capture-noise floor. Methods come from the estimator
registry (:mod:`thinfilm.core.registry`): every registered method of any role and source by
default, or ``--methods`` (names, aliases, ``package.module:function``).

Every generation and every (case, method) is one task of a Dask graph (:mod:`thinfilm.cluster`):
on a local cluster of ``--workers`` processes (default: one per core), on an existing cluster
(``--scheduler``), or in this process (``--workers 0``). Results do not depend on where tasks
run.

Output folder::

    DIR/benchmark.json                 what was asked (suite, options); marks the folder as ours
    DIR/datasets/<case>/               one generated dataset per case
    DIR/tasks/<case>/<kind>-<method>/  one folder per task: estimate/, evaluation/, task.json
    DIR/results.json                   every row (case, kind, method, metrics, timings)
    DIR/report.md                      leaderboards per kind, per-scene tables, the paper's
                                       figures beside ours, figures, failures, timings
    DIR/report.html                    the leaderboards and tasks for a browser: sortable, filtered
                                       by scene and method, a view per task (thinfilm.report_html)

Each task folder is written to a temporary folder and renamed into place with its marker
``task.json`` last, so a folder is there complete or not at all. ``--resume`` keeps the
datasets whose ``scene.toml`` is the case's spec and the tasks whose ``task.json`` records the
same task (spec, kind, method, thinfilm version) and success, and runs the rest; without it, an
earlier output of ours at ``DIR`` is replaced.

``--baseline OLD/results.json`` compares every metric of every (case, kind, method) with an
earlier run (:mod:`thinfilm.gate`), prints what got worse beyond the documented tolerances,
and sets the exit status: 1 on any regression, 0 otherwise. Without a baseline the exit status
is 1 when a task failed or a reconstruction kind has no method.
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
import traceback
from pathlib import Path

from thinfilm.core import signals
from thinfilm.core.errors import UserError
from thinfilm.suites import QUICK_RESOLUTION

__all__ = [
    "FORMAT",
    "PRESET_KINDS",
    "QUICK_RESOLUTION",
    "PAPER_FIGURES",
    "benchmark_methods",
    "select_methods",
    "plan_benchmark",
    "run_method",
    "run_benchmark",
    "write_report",
    "write_report_html",
    "cli_main",
]

FORMAT = "thinfilm-benchmark/2"
TASK_FORMAT = "thinfilm-benchmark-task/1"
#: what marks a folder as a benchmark output of ours (replaced by a new run)

#: Which reconstruction kinds apply to which preset (the ``presets`` suite).
PRESET_KINDS = {
    "hemisphere": ("rgb", "spectral"),
    "cylinder": ("rgb", "spectral"),
    "pyramid": ("rgb",),
}

#: Figures the paper reports (``docs/paper.md``), keyed by (kind, preset). ``setting``
#: says what the paper measured them on; ``None`` = not reported.
PAPER_FIGURES = {
    ("rgb", "cylinder"): {
        "setting": "real cylinder (PET, MgF2 400 nm)",
        "normal_error_deg": 4.48, "delta_e_ab": 0.64, "thickness_error_nm": None,
        "film_ior_error": None, "spectral_rmse_pct": None},
    ("rgb", "pyramid"): {
        "setting": "real pyramid button (ABS, MgF2 400-690 nm)",
        "normal_error_deg": 2.82, "delta_e_ab": 3.0, "thickness_error_nm": None,
        "film_ior_error": None, "spectral_rmse_pct": None},
    ("rgb", "hemisphere"): {
        "setting": "spectrometer sweep, 630 nm film, zenith 10-50 deg (Table 1)",
        "normal_error_deg": None, "delta_e_ab": None, "thickness_error_nm": 6.56,
        "film_ior_error": None, "spectral_rmse_pct": None},
    ("spectral", "hemisphere"): {
        "setting": "simulated hemisphere (400 nm); normal error is the max",
        "normal_error_deg": "max ~10", "delta_e_ab": None, "thickness_error_nm": "~10",
        "film_ior_error": 0.0, "spectral_rmse_pct": None},
    ("spectral", "cylinder"): {
        "setting": "simulated cylinder (420-560 nm); normal error is the max",
        "normal_error_deg": "max ~4", "delta_e_ab": None, "thickness_error_nm": "~7",
        "film_ior_error": 0.0, "spectral_rmse_pct": None},
    ("spectral", "real"): {
        "setting": "real sample (n2 1.37 estimated 1.41)",
        "normal_error_deg": None, "delta_e_ab": 3.33, "thickness_error_nm": 45.0,
        "film_ior_error": 0.04, "spectral_rmse_pct": "~2"},
}


# -- methods -------------------------------------------------------------------------------------

def benchmark_methods(kind: str) -> dict:
    """Every registered method of ``kind`` (any role, any source): name → role."""
    from thinfilm.core import registry

    return {m.name: m.role for m in registry.methods(kind)}


def select_methods(names=None, kinds=("rgb", "spectral")) -> dict:
    """The methods to benchmark, per kind: ``{kind: [Method, ...]}``.

    ``names`` (registry names, aliases or ``package.module:function``; a name may match
    methods of both kinds, as ``paper`` does) or, when None, every registered method of each
    kind, of any role and source. One-line :class:`UserError` for an unknown name."""
    from thinfilm.core import registry

    if names is None:
        return {k: list(registry.methods(k)) for k in kinds}
    found = registry.resolve(list(names))
    return {k: [m for m in found if m.kind == k] for k in kinds}


def _method_refs(names) -> dict:
    """``{(kind, method name): what a worker resolves it by}``: the name, or the
    ``package.module:function`` path it was given as (a worker has no record of it)."""
    from thinfilm.core import registry

    refs = {}
    for name in names or ():
        if ":" in name:
            for m in registry.resolve([name]):
                refs[(m.kind, m.name)] = name
    return refs


def _safe(name: str) -> str:
    """A method name as a folder name (``package.module:function`` → ``package.module_function``)."""
    return "".join(c if c.isalnum() or c in "._-" else "_" for c in name)


# -- the plan --------------------------------------------------------------------------------------

def plan_benchmark(suite, quick=False, methods=None, resolution=None, refine=False) -> dict:
    """Cases and tasks of a benchmark run, before anything runs.

    Parameters
    ----------
    suite : :class:`thinfilm.suites.Suite`, or a suite name or file
    quick : bool
        Cap the image size (:meth:`thinfilm.suites.Suite.cases`).
    methods : list of str, optional
        Method names (``--methods``); default the suite's ``methods``, else every
        registered method.
    resolution : int, optional
        Every case at this image size.
    refine : bool
        Also each kind's default method refined (:mod:`thinfilm.refine`): rows ``NAME+refine``.

    Returns
    -------
    dict with ``suite``, ``cases`` (:class:`~thinfilm.suites.Case`), ``methods``
    (``{kind: [Method]}``), ``missing_kinds`` and ``tasks``: one dict per (case, method)
    and per case's ground truth, in report order (``case``, ``kind``, ``method`` (a
    :class:`~thinfilm.core.registry.Method` or None for the ground truth), ``label``,
    ``folder``, ``key``).
    """
    from thinfilm import __version__
    from thinfilm.suites import Suite, load_suite

    if not isinstance(suite, Suite):
        suite = load_suite(suite)
    cases = suite.cases(quick=quick, resolution=resolution)
    names = methods if methods is not None else suite.methods
    kinds_needed = [k for k in ("rgb", "spectral") if any(k in c.kinds for c in cases)]
    chosen = select_methods(names, kinds_needed)
    refs = _method_refs(names)
    missing = {}
    if names is None:
        missing = {k: "no method registered" for k in kinds_needed if not chosen[k]}
    elif not any(chosen.values()):
        raise UserError(f"--methods {','.join(names)}: none of these methods applies to the scenes of "
                        f"suite {suite.name!r} (kinds {', '.join(kinds_needed)})")
    tasks = []
    for case in cases:
        spec_toml = case.spec.to_toml()
        tasks.append({"case": case, "kind": "-", "method": None, "label": "ground-truth",
                      "folder": f"tasks/{case.id}/ground-truth",
                      "key": _task_key(spec_toml, "-", "ground truth", "thinfilm", __version__)})
        for kind in case.kinds:
            for m in chosen.get(kind, []):
                label = f"{kind}-{_safe(m.name)}"
                tasks.append({"case": case, "kind": kind, "method": m, "label": label,
                              "ref": refs.get((kind, m.name), m.name),
                              "folder": f"tasks/{case.id}/{label}",
                              "key": _task_key(spec_toml, kind, m.name, m.source, __version__)})
                if refine and m.role == "default":
                    label = f"{kind}-{_safe(m.name)}-refine"
                    tasks.append({"case": case, "kind": kind, "method": m, "label": label,
                                  "ref": refs.get((kind, m.name), m.name), "refine": True,
                                  "folder": f"tasks/{case.id}/{label}",
                                  "key": _task_key(spec_toml, kind, f"{m.name}+refine", m.source, __version__)})
        if case.spec.rig.sensor == "dofp-rgb" and "rgb" in case.kinds:
            # the same scene through its colour polarization sensor's raw image: imported
            # (demosaiced), reconstructed, and scored against the scene's captures and truth
            for m in chosen.get("rgb", []):
                label = f"rgb-{_safe(m.name)}-mosaic"
                tasks.append({"case": case, "kind": "rgb", "method": m, "label": label,
                              "ref": refs.get(("rgb", m.name), m.name), "mosaic": True,
                              "folder": f"tasks/{case.id}/{label}",
                              "key": _task_key(spec_toml, "rgb-mosaic", m.name, m.source, __version__)})
    return {"suite": suite, "cases": cases, "methods": chosen, "missing_kinds": missing, "tasks": tasks,
            "quick": bool(quick), "resolution": resolution}


def _task_key(spec_toml, kind, method, source, version) -> str:
    text = json.dumps({"spec": spec_toml, "kind": kind, "method": method, "source": source,
                       "thinfilm": version}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


# -- tasks (run on Dask workers, or in this process) -----------------------------------------------

def run_method(kind: str, dataset: Path, out: Path, method: str, refine: bool = False) -> None:
    """Reconstruct ``dataset`` with registered ``method`` of ``kind`` into the folder ``out``
    (then refined on the dataset's captures, with ``refine``)."""
    from thinfilm.core.io import write_estimate
    from thinfilm.core.outputs import atomic_output_dir
    from thinfilm.reconstruct import reconstruct

    est, _ = reconstruct(kind, dataset, method)
    if refine:
        from thinfilm.refine import refine as refine_estimate

        est = refine_estimate(dataset, est)
    with atomic_output_dir(out, command="reconstruct", inputs=[dataset]) as tmp:
        write_estimate(tmp, est)


def _ground_truth_estimate(dataset: Path, out: Path) -> None:
    from thinfilm.core.io import Estimate, read_dataset, write_estimate
    from thinfilm.core.outputs import atomic_output_dir

    ds = read_dataset(dataset, need=("ground_truth",))
    gt = ds.ground_truth
    sub = ds.meta["substrate_ior"]
    if isinstance(sub, str):  # a material name: the estimate holds a number, the evaluation the dataset's table
        sub = ds.film().effective_substrate_index()
    est = Estimate(gt["normal"], gt["thickness"], gt["mask"], ds.meta["film_ior"], sub,
                   info={"method": "ground_truth", "timings_s": {}})
    with atomic_output_dir(out, command="reconstruct", inputs=[dataset]) as tmp:
        write_estimate(tmp, est)


def _evaluate(dataset: Path, estimate: Path, out: Path, figures: bool = True) -> dict:
    from thinfilm.core.variants import use_variant

    from . import evaluation

    use_variant()  # the evaluation re-renders in the generator's variant
    r = evaluation.evaluate(dataset, estimate, out, figures=figures)
    return {"metrics": r["metrics"], "coverage": r["info"]["coverage"],
            "film_ior_estimated": r["info"]["film_ior_estimated"]}


def _method_task(generated: dict, root: str, case_id: str, kind: str, method: str, role: str, source: str,
                 folder: str, key: str, name: str | None = None, figures: bool = True,
                 mosaic: bool = False, staged: str | None = None, refine: bool = False) -> dict:
    """Reconstruct and score one case with one method (``method``: a registry name or
    ``package.module:function``, None for the ground truth; ``name``: its registry name),
    reading ``root/datasets/case_id``. The task folder is written atomically (``task.json``
    last) at ``staged``, a staging path beside ``root/folder`` that the benchmark's process
    hands out (:meth:`thinfilm.core.outputs.OutputFolder.staging_path`; one of this process's
    when None), for that process to move into place; returns the result row with ``staged``."""
    from thinfilm.core.io import write_json
    from thinfilm.core.outputs import atomic_output_dir, staging_path

    root = Path(root)
    dataset = root / "datasets" / case_id
    source_dataset = root / "datasets" / f"{case_id}-mosaic" if mosaic else dataset
    row = {"scene": case_id, "kind": kind,
           "method": (name or method or "ground truth") + ("+refine" if refine else "") + (" (mosaic)" if mosaic else ""),
           "role": role, "source": source, "task": folder,
           "estimate": f"{folder}/estimate", "evaluation": f"{folder}/evaluation", "figures": bool(figures)}
    if generated.get("status") != "ok":
        row.update(status="failed", error=f"dataset not generated: {generated.get('error')}",
                   traceback=generated.get("traceback", ""))
        return row
    staged = Path(staged) if staged is not None else staging_path(root / folder)
    with atomic_output_dir(staged, command="benchmark-task", inputs=[dataset]) as tmp:
        try:
            t0 = time.perf_counter()
            if method is None:
                _ground_truth_estimate(dataset, tmp / "estimate")
            else:
                run_method(kind, source_dataset, tmp / "estimate", method, refine)
            row["reconstruct_s"] = round(time.perf_counter() - t0, 2)
            t0 = time.perf_counter()
            row.update(_evaluate(dataset, tmp / "estimate", tmp / "evaluation", figures))
            row["evaluate_s"] = round(time.perf_counter() - t0, 2)
            row["status"] = "ok"
        except Exception as e:  # one failing method must not hide the others
            signals.check_received()  # unless it is a signal that a library turned into an error
            row.update(status="failed", error=f"{type(e).__name__}: {e}".splitlines()[0],
                       traceback=traceback.format_exc(limit=6))
        write_json(tmp / "task.json", {"format": TASK_FORMAT, "key": key, "row": row})
    return dict(row, staged=str(staged))


def _import_task(root: str, case_id: str, staged: str) -> dict:
    """Import the raw sensor image of dataset ``case_id`` (``rig.sensor = "dofp-rgb"``) as the
    camera would be imported (``thinfilm import polarization --layout dofp-rgb``), into
    ``staged``. Returns ``{"status": "ok", "staged": ...}`` or the failure."""
    try:
        from thinfilm.core.io import read_json
        from thinfilm.importers.polarization import import_polarization

        folder = Path(root) / "datasets" / case_id
        meta = read_json(folder / "meta.json")
        sensor = meta["sensor"]
        import_polarization([folder / sensor["file"]], staged, "dofp-rgb", pattern=sensor["pattern"],
                            bit_depth=sensor["bits"], white_balance=",".join(repr(g) for g in sensor["white_balance"]),
                            camera=meta["camera"], illuminant=meta["illuminant"], film_ior=meta["film_ior"],
                            substrate_ior=meta["substrate_ior"], pixel_size=meta["projection"]["pixel_size"])
    except Exception as e:
        signals.check_received()
        return {"status": "failed", "error": f"{type(e).__name__}: {e}".splitlines()[0],
                "traceback": traceback.format_exc(limit=6)}
    return {"status": "ok", "staged": staged}


# -- resume ------------------------------------------------------------------------------------

def _finished_task(root: Path, task: dict):
    """The row of a finished, successful task with the same key, else None."""
    from thinfilm.core.io import read_json

    path = root / task["folder"] / "task.json"
    if not path.is_file():
        return None
    try:
        data = read_json(path)
    except (UserError, OSError):
        return None
    row = data.get("row") if isinstance(data, dict) else None
    if data.get("key") != task["key"] or not isinstance(row, dict) or row.get("status") != "ok":
        return None
    return row


def _finished_dataset(folder: Path, spec) -> bool:
    try:
        return (folder / "meta.json").is_file() and (folder / "scene.toml").read_text() == spec.to_toml()
    except OSError:
        return False


# -- the run -------------------------------------------------------------------------------------

def run_benchmark(out, suite="presets", quick=False, methods=None, resolution=None, resume=False,
                  workers=0, scheduler=None, progress=True, baseline=None, figures=True, refine=False) -> dict:
    """Run a benchmark into ``out`` and return its results (the ``results.json`` content).

    Parameters
    ----------
    out : folder; an earlier output of ours there is replaced, or resumed with ``resume``.
    suite, quick, methods, resolution, refine : see :func:`plan_benchmark`.
    resume : bool
        Keep finished datasets and tasks of an earlier run into ``out``.
    workers : int
        0 (default here): every task in this process; N: a local Dask cluster of N worker
        processes (the command's default is one per core).
    scheduler : str, optional
        Address or scheduler file of an existing Dask cluster (instead of ``workers``).
    baseline : dict, optional
        An earlier ``results.json`` content: the comparison goes into ``results["gate"]``
        and the report (:func:`thinfilm.gate.compare`).
    figures : bool
        Write each evaluation's PNG figures (about 2 s a task) and show them in the report.
    """
    from thinfilm.cluster import Task, executor, generate_task, run_tasks
    from thinfilm.core.outputs import OutputFolder, atomic_output_dir, open_output_dir

    t_start = time.perf_counter()
    plan = plan_benchmark(suite, quick=quick, methods=methods, resolution=resolution, refine=refine)
    suite = plan["suite"]
    inputs = [suite.path] if suite.path else []
    # --resume grows the earlier output in place, part by part; a new run is written aside and
    # swapped in whole (thinfilm.core.outputs)
    ctx = (open_output_dir(out, command="benchmark", inputs=inputs) if resume
           else atomic_output_dir(out, command="benchmark", inputs=inputs))
    with ctx as handle:
        folder = handle if resume else OutputFolder(handle, "benchmark")
        try:
            return _run(folder, plan, suite, resume, workers, scheduler, progress, baseline, figures, t_start,
                        Task, executor, generate_task, run_tasks)
        finally:
            folder.discard_staged()  # what an interrupted run had not moved into place yet


def _run(folder, plan, suite, resume, workers, scheduler, progress, baseline, figures, t_start,
         Task, executor, generate_task, run_tasks) -> dict:
    root = folder.path
    folder.write_text("benchmark.json", json.dumps({
        "format": FORMAT, "suite": suite.as_dict(), "quick": plan["quick"], "resolution": plan["resolution"],
        "methods": {k: [m.name for m in ms] for k, ms in plan["methods"].items()}}, indent=2, sort_keys=True) + "\n")

    rows, generated, todo = {}, {}, []
    for t in plan["tasks"]:
        row = _finished_task(root, t) if resume else None
        if row is not None:
            rows[t["folder"]] = dict(row, resumed=True)
        else:
            todo.append(t)
    cases = [c for c in plan["cases"] if any(t["case"] is c for t in todo)]
    # phase 1: the datasets the remaining tasks need (each written aside, then moved into place);
    # every part is moved into place as soon as it is done, so an interrupted run keeps it
    gen_tasks = []
    for case in cases:
        if resume and _finished_dataset(root / "datasets" / case.id, case.spec):
            generated[case.id] = {"status": "ok", "resumed": True}
        else:
            staged = folder.staging_path(f"datasets/{case.id}")
            gen_tasks.append(Task(f"generate/{case.id}", generate_task, (case.spec, str(staged)),
                                  label=f"generate {case.id}"))
    method_tasks = [Task(t["folder"], _method_task,
                         (None, str(root), t["case"].id, t["kind"], None if t["method"] is None else t["ref"],
                          "noise floor" if t["method"] is None else t["method"].role,
                          "thinfilm" if t["method"] is None else t["method"].source,
                          t["folder"], t["key"], None if t["method"] is None else t["method"].name, figures,
                          bool(t.get("mosaic")), None, bool(t.get("refine"))),
                         label=f"{t['case'].id}: {t['label']}") for t in todo]
    mosaic_cases = sorted({t["case"].id for t in todo if t.get("mosaic")})
    execution = {"mode": "nothing to run", "workers": 0}

    def adopt_dataset(task, value):
        case_id = task.key.split("/", 1)[1]
        if value.get("status") == "ok":
            folder.adopt(f"datasets/{case_id}{'-mosaic' if task.key.startswith('import/') else ''}",
                         value.pop("staged"))

    def adopt_task(task, value):
        staged = value.pop("staged", None) if isinstance(value, dict) else None
        if staged:
            folder.adopt(task.key, staged)

    if gen_tasks or method_tasks:
        with executor(workers, scheduler, max_workers=max(len(gen_tasks), len(method_tasks), 1)) as ex:
            for key, value in run_tasks(gen_tasks, ex, on_result=adopt_dataset, progress=progress,
                                        desc="datasets").items():
                generated[key.split("/", 1)[1]] = value
            # phase 2: the raw sensor images imported, where a scene has one
            imports = [Task(f"import/{c}", _import_task,
                            (str(root), c, str(folder.staging_path(f"datasets/{c}-mosaic"))),
                            label=f"import {c}") for c in mosaic_cases
                       if generated.get(c, {"status": "ok"}).get("status") == "ok"]
            imported = {}
            for key, value in run_tasks(imports, ex, on_result=adopt_dataset, progress=progress,
                                        desc="imports").items():
                imported[key.split("/", 1)[1]] = value
            for task in method_tasks:  # each task learns how its dataset went, and where to write
                case_id, mosaic = task.args[2], task.args[11]
                state = generated.get(case_id, {"status": "ok"})
                if mosaic and state.get("status") == "ok":  # through the mosaic
                    state = imported.get(case_id, {"status": "failed", "error": "not imported"})
                staged = str(folder.staging_path(task.key)) if state.get("status") == "ok" else None
                task.args = (state,) + task.args[1:12] + (staged,) + task.args[13:]
            for key, value in run_tasks(method_tasks, ex, on_result=adopt_task, progress=progress,
                                        desc="benchmark").items():
                rows[key] = value
            execution = ex.describe()
    n_cases = len(gen_tasks)
    ordered = []
    for t in plan["tasks"]:
        row = rows.get(t["folder"])
        if row is None or "scene" not in row:  # a task lost with its worker
            m = t["method"]
            row = dict({"scene": t["case"].id, "kind": t["kind"], "method": "ground truth" if m is None else m.name,
                        "role": "noise floor" if m is None else m.role, "source": "thinfilm" if m is None else m.source,
                        "task": t["folder"], "estimate": f"{t['folder']}/estimate",
                        "evaluation": f"{t['folder']}/evaluation", "status": "failed"},
                       error=(row or {}).get("error", "task did not run"), traceback=(row or {}).get("traceback", ""))
        ordered.append(row)
    resolution = plan["resolution"]
    graph = gen_tasks + method_tasks

    results = {
        "format": FORMAT,
        "suite": {"name": suite.name, "description": suite.description,
                  "path": str(suite.path) if suite.path else None},
        "quick": plan["quick"],
        "resolution": resolution,
        "scenes": [{"id": c.id, "scene": c.scene, "seed": c.seed, "source": c.spec.source,
                    "preset": _preset_of(suite, c.scene), "resolution": c.spec.rig.resolution,
                    "kinds": list(c.kinds), "dataset": f"datasets/{c.id}",
                    "generate_s": generated.get(c.id, {}).get("generate_s")} for c in plan["cases"]],
        "methods": {k: {m.name: {"role": m.role, "source": m.source} for m in ms}
                    for k, ms in plan["methods"].items()},
        "missing_kinds": plan["missing_kinds"],
        "rows": ordered,
        "execution": dict(execution, tasks_run=len(graph), datasets_generated=n_cases,
                          tasks_resumed=sum(1 for r in ordered if r.get("resumed"))),
        "timings_s": {"total": round(time.perf_counter() - t_start, 1)},
    }
    if baseline is not None:
        from thinfilm.gate import compare

        results["gate"] = compare(results, baseline)
    folder.write_text("results.json", json.dumps(results, indent=2, sort_keys=True) + "\n")
    folder.write_text("report.md", write_report(results))
    folder.write_text("report.html", write_report_html(results, root))
    return results


def _preset_of(suite, scene_name):
    from thinfilm.scenes import PRESETS

    spec = next(s.spec for s in suite.scenes if s.name == scene_name)
    return spec if spec in PRESETS else None


# -- report --------------------------------------------------------------------------------------

def _f(value, digits=2, scale=1.0):
    if value is None:
        return "—"
    if isinstance(value, str):
        return value
    return f"{value * scale:.{digits}f}"


def _stat(row, key, stat="mean", digits=2, scale=1.0):
    m = (row.get("metrics") or {}).get(key)
    if key == "film_ior_error":
        return _f(m, 3)
    return _f(None if m is None else m.get(stat), digits, scale)


def _pct(value):
    return "—" if value is None else f"{100 * value:.0f} %"


def _mean(values):
    values = [v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)]
    return sum(values) / len(values) if values else None


def leaderboard(results: dict, kind: str) -> list:
    """Methods of ``kind`` ranked: fewest failed cases first, then mean normal error, then
    mean ΔE*ab (means over the cases each method completed). One dict per method."""
    rows = [r for r in results["rows"] if r["kind"] == kind]
    out = []
    for name in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == name]
        ok = [r for r in mine if "error" not in r]

        def avg(key, stat="mean"):
            if key == "film_ior_error" or key.startswith("efficiency"):
                return _mean([(r.get("metrics") or {}).get(key) for r in ok])
            return _mean([((r.get("metrics") or {}).get(key) or {}).get(stat) for r in ok])

        out.append({"method": name, "role": mine[0].get("role"), "source": mine[0].get("source"),
                    "cases": len(mine), "failed": len(mine) - len(ok),
                    "normal_error_deg": avg("normal_error_deg"), "normal_error_p95": avg("normal_error_deg", "p95"),
                    "thickness_error_nm": avg("thickness_error_nm"), "delta_e_ab": avg("delta_e_ab"),
                    "delta_e_2000": avg("delta_e_2000"), "spectral_rmse": avg("spectral_rmse"),
                    "film_ior_error": avg("film_ior_error"),
                    "efficiency_normal": avg("efficiency_normal"),
                    "efficiency_thickness": avg("efficiency_thickness"),
                    "coverage": _mean([r.get("coverage") for r in ok]),
                    "reconstruct_s": _mean([r.get("reconstruct_s") for r in ok])})
    inf = float("inf")
    out.sort(key=lambda e: (e["failed"], inf if e["normal_error_deg"] is None else e["normal_error_deg"],
                            inf if e["delta_e_ab"] is None else e["delta_e_ab"], e["method"]))
    return out


_ROW_HEADER = ("| method | role | normal err. mean / p95 (°) | zenith err. mean (°) | thickness err. mean / p95 (nm) "
               "| n2 est. (err.) | ΔE*ab mean / p95 | ΔE00 mean | spectral RMSE mean (%) | coverage | reconstruct (s) |")


def _row_line(r) -> str:
    if "error" in r:
        return (f"| {r['method']} | {r['role']} | **failed**: {r['error'].replace('|', '/')} "
                f"|  |  |  |  |  |  |  |  |")
    fi = r.get("film_ior_estimated")
    n2 = (f"{fi:.3f}" if isinstance(fi, (int, float)) else str(fi)) + f" ({_stat(r, 'film_ior_error')})"
    return (f"| {r['method']} | {r['role']} | "
            f"{_stat(r, 'normal_error_deg')} / {_stat(r, 'normal_error_deg', 'p95')} | "
            f"{_stat(r, 'zenith_error_deg')} | "
            f"{_stat(r, 'thickness_error_nm', digits=1)} / {_stat(r, 'thickness_error_nm', 'p95', 1)} | "
            f"{n2} | {_stat(r, 'delta_e_ab')} / {_stat(r, 'delta_e_ab', 'p95')} | "
            f"{_stat(r, 'delta_e_2000')} | {_stat(r, 'spectral_rmse', scale=100.0)} | "
            f"{_pct(r.get('coverage'))} | {r.get('reconstruct_s', 0):.1f} |")


def write_report(results: dict) -> str:
    """The Markdown text of ``report.md``."""
    rows = results["rows"]
    res = (f"{results['resolution']} px" if results.get("resolution")
           else f"at most {QUICK_RESOLUTION} px (or the suite's quick_resolution)" if results.get("quick")
           else "each scene's own size")
    suite = results.get("suite") or {}
    ex = results.get("execution") or {}
    where = {"in-process": "in one process", "local-cluster": f"on a local Dask cluster of {ex.get('workers')} workers",
             "scheduler": f"on a Dask cluster of {ex.get('workers')} workers"}.get(ex.get("mode"), "")
    lines = [
        "# thinfilm benchmark report",
        "",
        f"Suite **{suite.get('name', '?')}**" + (f": {suite['description']}" if suite.get("description") else "") + ".",
        "",
        f"{'Quick run' if results.get('quick') else 'Full run'}: images {res}, total wall time "
        f"{results['timings_s'].get('total', 0):.0f} s {where}"
        + (f" ({ex.get('tasks_resumed')} tasks resumed)" if ex.get("tasks_resumed") else "") + ".",
        "",
        "Every estimate is re-rendered through the `thinfilm` BSDF with the dataset's rig (no "
        "noise) and compared with the captures. ΔE*ab (CIE 1976, paper Eq. 31) and ΔE00 are "
        "taken between the captured and re-rendered s-polarized spectra in CIELAB (CIE 1931 2°, "
        "the dataset illuminant, perfect-white reference); spectral RMSE is paper Eq. 32 in "
        "percent reflectance. Errors are over the object mask where the estimate is valid; "
        "*coverage* is that fraction of the object. The *ground truth* row is the truth itself "
        "scored against the noisy captures: its ΔE is the capture-noise floor.",
        "",
    ]
    if results.get("missing_kinds"):
        lines += ["**Not benchmarked** (not available in this version):", ""]
        lines += [f"- `{k}`: {v}" for k, v in results["missing_kinds"].items()]
        lines.append("")

    gate = results.get("gate")
    if gate is not None:
        from thinfilm.gate import gate_markdown

        lines += gate_markdown(gate)

    lines += ["## Leaderboards", "",
              "Methods ranked by the number of failed scenes, then the mean normal error, then the "
              "mean ΔE*ab; each figure is the mean over the scenes the method completed of that "
              "scene's mean (p95: of its 95th percentile). *Efficiency* is the per-pixel Cramér-Rao "
              "bound's RMS over the error's RMS on the pixels of true zenith 15-75° (1: an efficient "
              "unbiased estimator; above 1 only with priors or bias).", ""]
    for kind in ("rgb", "spectral"):
        board = leaderboard(results, kind)
        if not board:
            continue
        lines += [f"### {kind}", "",
                  "| rank | method | role | source | scenes (failed) | normal err. mean / p95 (°) | "
                  "thickness err. mean (nm) | ΔE*ab | ΔE00 | spectral RMSE (%) | n2 err. | "
                  "efficiency normal / thickness | coverage | reconstruct (s) |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for i, e in enumerate(board, 1):
            lines.append(
                f"| {i} | {e['method']} | {e['role']} | {e['source'] or '—'} | {e['cases']} ({e['failed']}) | "
                f"{_f(e['normal_error_deg'])} / {_f(e['normal_error_p95'])} | {_f(e['thickness_error_nm'], 1)} | "
                f"{_f(e['delta_e_ab'])} | {_f(e['delta_e_2000'])} | {_f(e['spectral_rmse'], scale=100.0)} | "
                f"{_f(e['film_ior_error'], 3)} | "
                f"{_f(e['efficiency_normal'])} / {_f(e['efficiency_thickness'])} | "
                f"{_pct(e['coverage'])} | "
                f"{_f(e['reconstruct_s'], 1)} |")
        lines.append("")

    lines += ["## Scenes", ""]
    for sc in results.get("scenes", []):
        mine = [r for r in rows if r["scene"] == sc["id"]]
        lines += [f"### {sc['id']}", "",
                  f"{sc.get('source', '')}, seed {sc.get('seed')}, {sc.get('resolution')} px, kinds "
                  f"{', '.join(sc.get('kinds', []))}; dataset `{sc.get('dataset')}`.", ""]
        for kind in ("-", "rgb", "spectral"):
            kr = [r for r in mine if r["kind"] == kind]
            if not kr:
                continue
            lines += [f"*{'ground truth' if kind == '-' else kind}*", "", _ROW_HEADER,
                      "|---|---|---|---|---|---|---|---|---|---|---|"]
            lines += [_row_line(r) for r in kr]
            lines.append("")

    lines += ["## Paper versus ours", "",
              "The paper's figures (Kobayashi et al.; `docs/paper.md`) beside ours on the "
              "matching preset. The paper's RGB figures come from real objects or a "
              "spectrometer sweep, its spectral figures from simulation (and one real sample): "
              "the settings differ, so read the columns side by side, not as a pass mark.", "",
              "| kind | preset | paper setting | normal err. (°) paper / ours | thickness err. (nm) "
              "paper / ours | n2 err. paper / ours | ΔE*ab paper / ours | spectral RMSE (%) paper / ours |",
              "|---|---|---|---|---|---|---|---|"]
    preset_of = {sc["id"]: sc.get("preset") for sc in results.get("scenes", [])}
    for (kind, preset), paper in PAPER_FIGURES.items():
        ours = [r for r in rows if r["kind"] == kind and "error" not in r
                and (preset_of.get(r["scene"]) == preset
                     or (preset == "real" and preset_of.get(r["scene"]) in ("hemisphere", "cylinder")))]
        if not ours:
            ours = [None]
        for r in ours:
            def pair(key, stat="mean", digits=2, scale=1.0, paper_key=None):
                p = _f(paper.get(paper_key or key), digits)
                if r is None:
                    return f"{p} / —"
                if key == "film_ior_error":
                    return f"{p} / {_stat(r, key)}"
                max_too = isinstance(paper.get(paper_key or key), str) and "max" in paper[paper_key or key]
                o = _stat(r, key, "max" if max_too else stat, digits, scale)
                return f"{p} / {('max ' if max_too else '') + o}"
            who = "" if r is None else f" ({r['scene']}, {r['method']})"
            lines.append(
                f"| {kind} | {preset}{who} | {paper['setting']} | {pair('normal_error_deg')} | "
                f"{pair('thickness_error_nm', digits=1)} | {pair('film_ior_error')} | "
                f"{pair('delta_e_ab')} | {pair('spectral_rmse', scale=100.0, paper_key='spectral_rmse_pct')} |")
    lines.append("")

    if any("error" not in r and r.get("figures") is not False for r in rows):
        lines += ["## Figures", ""]
    for r in rows:
        if "error" in r or r.get("figures") is False:
            continue
        ev = r["evaluation"]
        lines += [f"### {r['scene']} — {r['method']} ({r['kind']}, {r['role']})", ""]
        for name, alt in (("appearance.png", "captured vs re-rendered, ΔE*ab"),
                          ("normals.png", "normals: truth, estimate, error"),
                          ("thickness.png", "thickness: truth, estimate, error"),
                          ("errors.png", "error maps")):
            if r["method"] == "ground truth" and name in ("normals.png", "thickness.png"):
                continue
            lines.append(f"![{alt}]({ev}/{name})")
        lines.append("")

    failed = [r for r in rows if "error" in r]
    if failed:
        lines += ["## Failures", ""]
        for r in failed:
            lines += [f"### {r['scene']} — {r['kind']} {r['method']}", "", f"{r['error']}", "", "```",
                      (r.get("traceback") or "").rstrip(), "```", ""]
    lines += ["## Timings (s)", "", "| step | seconds |", "|---|---|"]
    lines += [f"| total | {results['timings_s'].get('total')} |"]
    lines += [f"| generate {sc['id']} | {sc['generate_s']} |" for sc in results.get("scenes", [])
              if sc.get("generate_s") is not None]
    lines += [f"| reconstruct+evaluate {r['scene']}/{r['method'] if r['kind'] == '-' else r['kind'] + '-' + r['method']} | "
              f"{(r.get('reconstruct_s') or 0) + (r.get('evaluate_s') or 0):.1f} |" for r in rows
              if "error" not in r and not r.get("resumed")]
    lines.append("")
    return "\n".join(lines)


def write_report_html(results: dict, root=None) -> str:
    """The HTML text of ``report.html`` (:mod:`thinfilm.report_html`): the leaderboards of
    every kind, over all scenes and over each, the tasks, and a view per task. ``root``: the
    output folder, so that the report shows only the figures there."""
    from thinfilm.report_html import render_report_html

    rows = results["rows"]
    boards = {}
    for kind in ("rgb", "spectral"):
        scenes = dict.fromkeys(r["scene"] for r in rows if r["kind"] == kind)
        boards[kind] = {"": leaderboard(results, kind)}
        boards[kind].update({s: leaderboard({"rows": [r for r in rows if r["scene"] == s]}, kind) for s in scenes})
    return render_report_html(results, boards, root)


# -- command line ----------------------------------------------------------------------------------

def _method_list(text):
    if text is None:
        return None
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise UserError(f"--methods {text!r}: expected method names separated by commas")
    return names


def cli_main(args) -> int:
    """``thinfilm benchmark``: see the module docstring. Exit status 1 when a task failed or a
    kind has no method; with ``--baseline``, 1 on any regression and 0 otherwise."""
    out = Path(args.out)
    baseline = None
    base_path = getattr(args, "baseline", None)
    if base_path is not None:
        from thinfilm.gate import read_baseline

        baseline = read_baseline(base_path)
    scheduler = getattr(args, "scheduler", None)
    workers = getattr(args, "workers", None)
    if scheduler is not None and workers is not None:
        raise UserError("--workers and --scheduler: give one of them (a scheduler's cluster has its own workers)")
    if scheduler is None and workers is None:
        from thinfilm.cluster import auto_workers

        workers = auto_workers()
    results = run_benchmark(out, suite=getattr(args, "suite", None) or "presets", quick=args.quick,
                            methods=_method_list(getattr(args, "methods", None)),
                            resolution=getattr(args, "resolution", None), resume=getattr(args, "resume", False),
                            workers=workers, scheduler=scheduler, progress=sys.stderr.isatty(),
                            baseline=baseline, figures=not getattr(args, "no_figures", False),
                            refine=getattr(args, "refine", False))
    rows = results["rows"]
    failed = [r for r in rows if "error" in r]
    ex = results["execution"]
    print(f"benchmark: suite {results['suite']['name']}, {len(rows)} tasks ({ex['tasks_resumed']} resumed), "
          f"{len(failed)} failed, {results['timings_s']['total']:.0f} s -> {out / 'report.md'}")
    for r in failed:
        print(f"  failed: {r['scene']} {r['kind']} {r['method']}: {r['error']}", file=sys.stderr)
    for k, v in (results.get("missing_kinds") or {}).items():
        print(f"  not benchmarked: {k}: {v}", file=sys.stderr)
    if baseline is not None:
        from thinfilm.gate import gate_text

        gate = results["gate"]
        print(gate_text(gate, base_path))
        return 1 if gate["regressions"] else 0
    return 1 if failed or results.get("missing_kinds") else 0


def _main(argv=None) -> int:  # pragma: no cover - `python -m thinfilm.benchmark`
    from thinfilm.cli import main

    return main(["benchmark", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":  # pragma: no cover
    sys.exit(_main())
