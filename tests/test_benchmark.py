"""``thinfilm benchmark``: suites, one folder per task, resume, the report, the regression gate."""

from __future__ import annotations

import copy
import json
import re

import pytest

from thinfilm import benchmark, gate, suites
from thinfilm.cli import main
from thinfilm.core.errors import UserError

# 21 bands instead of 81 and tiny images: the tests check the machinery, not accuracy
FAST = ["rig.wavelengths_nm = { start = 400.0, stop = 720.0, step = 16.0 }"]


def _suite(tmp_path, scenes, extra=""):
    """A suite file in tmp_path; ``scenes`` is a list of TOML bodies of [[scenes]] tables."""
    path = tmp_path / "suite.toml"
    path.write_text('name = "tiny"\ndescription = "test suite"\n' + extra + "\n"
                    + "\n".join(f"[[scenes]]\n{body}\n" for body in scenes))
    return path


def _tiny(tmp_path, **extra):
    overrides = json.dumps(FAST)
    return _suite(tmp_path, [f'name = "pyr"\nspec = "pyramid"\nresolution = 24\nkinds = ["rgb"]\n'
                             f'overrides = {overrides}'], **extra)


# -- suites ------------------------------------------------------------------------------------------

def test_presets_suite_is_todays_benchmark_and_its_rough_versions():
    suite = suites.load_suite("presets")
    assert "presets" in suites.known_suites()
    smooth = [s for s in suite.scenes if "rough" not in s.name]
    assert {s.name: s.kinds for s in smooth} == benchmark.PRESET_KINDS
    assert [c.spec.rig.resolution for c in suite.cases(quick=True)][:3] == [128, 128, 128]
    assert [c.spec.rig.resolution for c in suite.cases()][:3] == [256, 256, 256]
    assert {c.spec.rig.resolution for c in suite.cases(resolution=40)} == {40}
    # each preset at alpha 0.02, 0.05 and 0.1, with the preset's kinds; 128 px, 64 px quick
    rough = [c for c in suite.cases(quick=True) if c.spec.roughness]
    assert sorted((c.spec.shape.kind, c.spec.roughness) for c in rough) == sorted(
        (k, a) for k in ("hemisphere", "cylinder", "pyramid") for a in (0.02, 0.05, 0.1))
    assert all(c.kinds == benchmark.PRESET_KINDS[c.spec.shape.kind] for c in rough)
    assert {c.spec.rig.resolution for c in rough} == {64}
    assert {c.spec.rig.resolution for c in suite.cases() if c.spec.roughness} == {128}


def test_suite_file_paths_seeds_overrides_and_quick_resolution(tmp_path):
    (tmp_path / "specs").mkdir()
    (tmp_path / "specs" / "cyl.toml").write_text('[shape]\nkind = "cylinder"\n[rig]\nresolution = 200\n')
    sub = tmp_path / "suites"
    sub.mkdir()
    path = _suite(sub, ['name = "cyl"\nspec = "../specs/cyl.toml"\nseeds = [3, 4]\n'
                        'overrides = ["film.thickness.value=450"]\nkinds = ["spectral"]',
                        'name = "hemi"\nspec = "hemisphere"\nresolution = 64',
                        'name = "pyr"\nspec = "pyramid"\nresolution = 100\nquick_resolution = 32'],
                  extra="quick_resolution = 96\nmethods = [\"eikonal\"]")
    suite = suites.load_suite(path)
    assert suite.methods == ("eikonal",)
    cases = suite.cases(quick=True)
    assert [(c.id, c.seed, c.kinds) for c in cases] == [("cyl-s3", 3, ("spectral",)), ("cyl-s4", 4, ("spectral",)),
                                                        ("hemi", 0, ("rgb", "spectral")),
                                                        ("pyr", 0, ("rgb", "spectral"))]
    assert [c.spec.rig.resolution for c in cases] == [96, 96, 64, 32]
    assert cases[0].spec.shape.kind == "cylinder" and cases[0].spec.thickness["value"] == 450.0
    assert [c.spec.rig.resolution for c in suite.cases()] == [200, 200, 64, 100]


@pytest.mark.parametrize("body, message", [
    ('name = "a"\nspec = "nowhere.toml"', "neither a file"),
    ('name = "a b"\nspec = "pyramid"', "'name' must be"),
    ('name = "a"\nspec = "pyramid"\nkinds = ["depth"]', "'kinds' must be"),
    ('name = "a"\nspec = "pyramid"\nseeds = [1, 1]', "'seeds' must be"),
    ('name = "a"\nspec = "pyramid"\nresolution = 0', "'resolution' must be"),
    ('name = "a"\nspec = "pyramid"\ncolour = 1', "unknown key 'colour'"),
])
def test_bad_suites_are_one_line_errors(tmp_path, body, message):
    with pytest.raises(UserError, match=message) as e:
        suites.load_suite(_suite(tmp_path, [body]))
    assert "\n" not in str(e.value)


def test_unknown_suite_names_the_known_ones(capsys):
    assert main(["benchmark", "--suite", "nosuch", "--out", "never-written"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown suite" in err and "presets" in err


def test_unknown_method_is_one_line_error(tmp_path, capsys):
    assert main(["benchmark", "--suite", str(_tiny(tmp_path)), "--methods", "nosuch", "--workers", "0",
                 "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nosuch" in err
    assert not (tmp_path / "out").exists()


def test_workers_and_scheduler_exclude_each_other(tmp_path, capsys):
    assert main(["benchmark", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1", "--out",
                 str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--workers and --scheduler" in err
    with pytest.raises(SystemExit) as e:  # a usage error
        main(["benchmark", "--workers", "-1", "--out", str(tmp_path / "out")])
    assert e.value.code == 2 and "--workers" in capsys.readouterr().err


def test_plan_has_every_method_of_any_role_and_source():
    from thinfilm.core import registry

    plan = benchmark.plan_benchmark("presets", quick=True)
    planned = {(t["case"].id, t["kind"], t["method"].name) for t in plan["tasks"] if t["method"] is not None}
    for m in registry.methods():
        for case, kinds in benchmark.PRESET_KINDS.items():
            assert ((case, m.kind, m.name) in planned) == (m.kind in kinds)
    only = benchmark.plan_benchmark("presets", methods=["coherent", "paper"])
    names = {(t["kind"], t["method"].name) for t in only["tasks"] if t["method"] is not None}
    assert names == {("rgb", "coherent"), ("rgb", "kobayashi2023"), ("spectral", "kobayashi")}


# -- a run ---------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """One small in-process run: the pyramid at 24 px, ground truth and both RGB methods."""
    root = tmp_path_factory.mktemp("bench")
    out = root / "run"
    results = benchmark.run_benchmark(out, suite=_tiny(root), methods=["coherent", "paper"], workers=0,
                                      progress=False)
    return out, results


@pytest.mark.slow
def test_run_writes_one_folder_per_task_and_a_complete_report(tiny_run):
    out, results = tiny_run
    rows = results["rows"]
    assert not [r for r in rows if "error" in r], [r.get("traceback") for r in rows]
    assert [(r["scene"], r["kind"], r["method"]) for r in rows] == [
        ("pyr", "-", "ground truth"), ("pyr", "rgb", "coherent"), ("pyr", "rgb", "kobayashi2023")]
    assert json.loads((out / "results.json").read_text())["rows"] == json.loads(json.dumps(rows))
    for r in rows:
        task = json.loads((out / r["task"] / "task.json").read_text())
        assert task["row"] == json.loads(json.dumps(r))
        assert json.loads((out / r["evaluation"] / "metrics.json").read_text()) == r["metrics"]
        assert (out / r["estimate"] / "estimate.exr").is_file()
    report = (out / "report.md").read_text()
    assert "## Leaderboards" in report and "### rgb" in report
    board = benchmark.leaderboard(results, "rgb")
    assert [e["method"] for e in board] == sorted([e["method"] for e in board],
                                                  key=lambda m: next(r["metrics"]["normal_error_deg"]["mean"]
                                                                     for r in rows if r["method"] == m))
    assert f"| 1 | {board[0]['method']} |" in report
    # the paper's pyramid figures stand beside ours (the scene's spec is the pyramid preset)
    assert "| 2.82 / " in report and "| 3.00 / " in report
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", report)
    assert links and all((out / link).is_file() for link in links)
    gt = rows[0]
    assert gt["metrics"]["normal_error_deg"]["max"] == 0.0
    assert gt["metrics"]["delta_e_ab"]["mean"] < 1.0


@pytest.mark.slow
def test_resume_skips_finished_tasks_and_reruns_the_others(tiny_run, tmp_path):
    import shutil

    out0, first = tiny_run
    out = tmp_path / "run"
    shutil.copytree(out0, out)
    dataset = out / "datasets" / "pyr" / "spectral_s.exr"
    stamp = dataset.stat().st_mtime_ns
    # one task's marker records another task: it must run again; another task lost its folder
    task_json = out / "tasks" / "pyr" / "rgb-coherent" / "task.json"
    data = json.loads(task_json.read_text())
    data["key"] = "something else"
    task_json.write_text(json.dumps(data))
    shutil.rmtree(out / "tasks" / "pyr" / "ground-truth")
    again = benchmark.run_benchmark(out, suite=_tiny(tmp_path), methods=["coherent", "paper"], workers=0,
                                    resume=True, progress=False, figures=False)
    resumed = {r["method"]: bool(r.get("resumed")) for r in again["rows"]}
    assert resumed == {"ground truth": False, "kobayashi2023": True, "coherent": False}
    assert dataset.stat().st_mtime_ns == stamp  # the dataset was kept
    assert [r["metrics"] for r in again["rows"]] == [r["metrics"] for r in first["rows"]]
    assert again["execution"]["tasks_run"] == 2 and again["execution"]["datasets_generated"] == 0
    # without --resume the folder is replaced by a new run
    fresh = benchmark.run_benchmark(out, suite=_tiny(tmp_path), methods=["paper"], workers=0, progress=False,
                                    figures=False)
    assert not any(r.get("resumed") for r in fresh["rows"])
    assert not list(out.glob("tasks/*/*/evaluation/*.png")) and "## Figures" not in (out / "report.md").read_text()
    assert not (out / "tasks" / "pyr" / "rgb-coherent").exists()


@pytest.mark.slow
def test_failures_are_rows_with_a_section_and_exit_1(tiny_run, tmp_path, capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    (tmp_path / "broken_estimator.py").write_text(
        "from thinfilm.core.registry import estimator\n"
        "@estimator('broken', kind='rgb', needs=('polarized_rgb',))\n"
        "def broken(dataset, options):\n    raise RuntimeError('boom')\n")
    code = main(["benchmark", "--suite", str(_tiny(tmp_path)), "--methods", "broken_estimator:broken",
                 "--workers", "0", "--no-figures", "--out", str(tmp_path / "out")])
    assert code == 1
    err = capsys.readouterr().err
    assert "failed: pyr rgb broken:" in err and "RuntimeError: boom" in err
    report = (tmp_path / "out" / "report.md").read_text()
    assert "**failed**:" in report and "RuntimeError: boom" in report and "## Failures" in report
    assert "tasks/pyr/rgb-broken/evaluation/" not in report  # no figures of a failed run
    task = json.loads((tmp_path / "out" / "tasks" / "pyr" / "rgb-broken" / "task.json").read_text())
    assert task["row"]["status"] == "failed"


def test_report_lists_failures_and_missing_kinds():
    metrics = {k: {"mean": 1.0, "median": 1.0, "p95": 2.0, "max": 3.0}
               for k in ("normal_error_deg", "zenith_error_deg", "thickness_error_nm", "delta_e_ab",
                         "delta_e_2000", "spectral_rmse")}
    metrics["film_ior_error"] = 0.01
    results = {
        "suite": {"name": "presets"}, "quick": True, "resolution": 32, "missing_kinds": {"spectral": "module missing"},
        "timings_s": {"total": 12.0}, "execution": {"mode": "in-process"},
        "scenes": [{"id": "cylinder", "preset": "cylinder", "seed": 0, "resolution": 32, "kinds": ["rgb"]}],
        "rows": [
            {"scene": "cylinder", "kind": "rgb", "method": "a", "role": "paper", "metrics": metrics,
             "coverage": 0.5, "film_ior_estimated": 1.38, "evaluation": "tasks/cylinder/rgb-a/evaluation",
             "reconstruct_s": 1.0, "evaluate_s": 1.0},
            {"scene": "cylinder", "kind": "rgb", "method": "b", "role": "default",
             "error": "RuntimeError: boom", "traceback": "Traceback ...\nRuntimeError: boom",
             "evaluation": "tasks/cylinder/rgb-b/evaluation"},
        ],
    }
    text = benchmark.write_report(results)
    assert "**failed**: RuntimeError: boom" in text
    assert "`spectral`: module missing" in text
    assert "| a | paper | 1.00 / 2.00 |" in text
    assert "1.380 (0.010)" in text and "| 50 % |" in text
    assert "4.48 / 1.00" in text  # paper's cylinder normal error beside ours
    assert "tasks/cylinder/rgb-b/evaluation/" not in text  # no figures for a failed run
    assert "| 1 | a | paper |" in text and "| 2 | b | default |" in text  # failures rank last


# -- the regression gate ---------------------------------------------------------------------------

def _row(method="m", normal=1.0, coverage=1.0, **extra):
    stats = {"mean": normal, "median": normal, "p95": 2 * normal, "max": 3 * normal}
    return dict({"scene": "s", "kind": "rgb", "method": method, "coverage": coverage,
                 "metrics": {"normal_error_deg": stats, "delta_e_ab": {"mean": 1.0}, "film_ior_error": 0.0}}, **extra)


def test_gate_tolerances_missing_failed_and_new_rows():
    base = {"rows": [_row("a"), _row("b"), _row("c"), _row("d", error="old failure")]}
    now = {"rows": [_row("a", normal=1.09), _row("b", normal=1.2, coverage=0.95), _row("e")]}
    g = gate.compare(now, base)
    found = {(f["method"], f["metric"]) for f in g["regressions"]}
    # a: within 10 %; b: normals 20 % worse at every statistic, coverage down 5 %; c: missing
    assert ("a", "normal_error_deg.mean") not in found
    assert {("b", "normal_error_deg.mean"), ("b", "normal_error_deg.median"), ("b", "normal_error_deg.p95"),
            ("b", "coverage"), ("c", "-")} <= found
    assert ("b", "normal_error_deg.max") not in found  # one pixel: twice the tolerance (3.6 <= 3 + 0.6)
    assert g["new"] == [{"scene": "s", "kind": "rgb", "method": "e"}]
    assert g["skipped"] == [{"scene": "s", "kind": "rgb", "method": "d"}]
    failed_now = gate.compare({"rows": [_row("a", error="RuntimeError: x")]}, {"rows": [_row("a")]})
    assert failed_now["regressions"][0]["problem"].startswith("failed")
    lost = gate.compare({"rows": [_row("a", metrics={})]}, {"rows": [_row("a")]})
    assert {f.get("problem") for f in lost["regressions"]} == {"no value"}
    text = gate.gate_text(g, "OLD")
    assert "3 rows" not in text and "regressions" in text and "normal_error_deg.mean" in text


@pytest.mark.slow
def test_gate_exits_0_against_itself_and_1_against_ten_times_better_normals(tiny_run, tmp_path, capsys):
    import shutil

    out0, first = tiny_run
    out = tmp_path / "run"
    shutil.copytree(out0, out)
    args = ["benchmark", "--suite", str(_tiny(tmp_path)), "--methods", "coherent,paper", "--workers", "0",
            "--resume", "--out", str(out)]
    assert main(args + ["--baseline", str(out0 / "results.json")]) == 0
    assert "0 regressions" in capsys.readouterr().out
    better = copy.deepcopy(first)
    for r in better["rows"]:
        for stat in ("mean", "median", "p95", "max"):
            r["metrics"]["normal_error_deg"][stat] /= 10.0
    (tmp_path / "better.json").write_text(json.dumps(better))
    assert main(args + ["--baseline", str(tmp_path / "better.json")]) == 1
    printed = capsys.readouterr().out
    assert "normal_error_deg.mean" in printed and "coherent" in printed and "kobayashi2023" in printed
    assert "## Regression gate" in (out / "report.md").read_text()


@pytest.mark.slow
def test_a_scene_with_a_colour_polarization_sensor_is_also_scored_through_its_mosaic(tmp_path):
    """``rig.sensor = "dofp-rgb"``: the RGB methods run on the direct captures and on the import
    of the raw sensor image (``METHOD (mosaic)`` rows), both scored against the scene."""
    overrides = json.dumps(["rig.sensor=dofp-rgb"])
    path = _suite(tmp_path, [f'name = "cyl"\nspec = "cylinder"\nresolution = 64\nkinds = ["rgb"]\n'
                             f'overrides = {overrides}'])
    results = benchmark.run_benchmark(tmp_path / "out", suite=path, methods=["coherent"], progress=False,
                                      figures=False)
    rows = {r["method"]: r for r in results["rows"]}
    assert set(rows) == {"ground truth", "coherent", "coherent (mosaic)"}
    assert all(r["status"] == "ok" for r in rows.values()), [r.get("error") for r in rows.values()]
    assert (tmp_path / "out" / "datasets" / "cyl-mosaic" / "polarized_rgb.exr").is_file()
    direct, mosaic = rows["coherent"]["metrics"], rows["coherent (mosaic)"]["metrics"]
    # the mosaic costs a little accuracy, not a broken reconstruction
    assert mosaic["normal_error_deg"]["mean"] < direct["normal_error_deg"]["mean"] + 1.5
    assert mosaic["thickness_error_nm"]["mean"] < direct["thickness_error_nm"]["mean"] + 5.0
    assert "coherent (mosaic)" in (tmp_path / "out" / "report.md").read_text()


def test_refine_adds_a_refined_row_for_the_default(tmp_path):
    """``benchmark --refine``: beside every method, the kind's default refined on the captures
    (``coherent+refine``), scored like any row and in the leaderboard."""
    out = tmp_path / "b"
    assert main(["benchmark", "--suite", str(_tiny(tmp_path)), "--out", str(out), "--workers", "0",
                 "--methods", "coherent", "--refine", "--no-figures"]) == 0
    results = json.loads((out / "results.json").read_text())
    methods = {r["method"] for r in results["rows"]}
    assert {"coherent", "coherent+refine"} <= methods
    refined = next(r for r in results["rows"] if r["method"] == "coherent+refine")
    assert refined["status"] == "ok" and refined["metrics"]["normal_within_2sigma"] is not None
    est = json.loads((out / refined["estimate"] / "estimate.json").read_text())
    assert est["method"] == "coherent+refine" and est["refine"]["capture"] == "polarized_rgb"
    assert "coherent+refine" in (out / "report.md").read_text()
