"""``thinfilm benchmark``: the run writes a complete report; the report shows failures."""

from __future__ import annotations

import json
import re

import pytest

from thinfilm import benchmark


@pytest.mark.slow
def test_benchmark_run_on_one_small_preset(tmp_path):
    out = tmp_path / "bench"
    results = benchmark.run_benchmark(out, presets=["pyramid"], resolution=24, progress=False)
    rows = results["rows"]
    assert not [r for r in rows if "error" in r], [r.get("traceback") for r in rows]
    # ground truth plus the paper and default RGB methods; no spectral method on the pyramid
    methods = {(r["kind"], r["role"]) for r in rows}
    assert ("-", "noise floor") in methods
    assert any(k == "rgb" and "paper" in role for k, role in methods)
    assert any(k == "rgb" and "default" in role for k, role in methods)
    assert not any(k == "spectral" for k, _ in methods)
    report = (out / "report.md").read_text()
    assert json.loads((out / "results.json").read_text())["rows"] == json.loads(json.dumps(rows))
    for r in rows:
        assert f"| pyramid | {r['kind']} | {r['method']} |" in report
        m = json.loads((out / r["evaluation"] / "metrics.json").read_text())
        assert m == r["metrics"]
    # the paper's pyramid figures stand beside ours
    assert "| 2.82 / " in report and "| 3.00 / " in report
    # every embedded figure exists
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", report)
    assert links and all((out / link).is_file() for link in links)
    # the ground truth re-renders the noisy captures to within the noise floor
    gt = next(r for r in rows if r["method"] == "ground truth")
    assert gt["metrics"]["normal_error_deg"]["max"] == 0.0
    assert gt["metrics"]["delta_e_ab"]["mean"] < 1.0


def test_report_lists_failures_and_missing_kinds():
    metrics = {k: {"mean": 1.0, "median": 1.0, "p95": 2.0, "max": 3.0}
               for k in ("normal_error_deg", "zenith_error_deg", "thickness_error_nm", "delta_e_ab",
                         "delta_e_2000", "spectral_rmse")}
    metrics["film_ior_error"] = 0.01
    results = {
        "quick": True, "resolution": 32, "missing_kinds": {"spectral": "module missing"},
        "timings_s": {"total": 12.0},
        "rows": [
            {"preset": "cylinder", "kind": "rgb", "method": "a", "role": "paper", "metrics": metrics,
             "coverage": 0.5, "film_ior_estimated": 1.38, "evaluation": "evaluations/cylinder/rgb-a",
             "reconstruct_s": 1.0, "evaluate_s": 1.0},
            {"preset": "cylinder", "kind": "rgb", "method": "b", "role": "default",
             "error": "RuntimeError: boom", "traceback": "Traceback ...\nRuntimeError: boom",
             "evaluation": "evaluations/cylinder/rgb-b"},
        ],
    }
    text = benchmark.write_report(results)
    assert "**failed**: RuntimeError: boom" in text
    assert "`spectral`: module missing" in text
    assert "| cylinder | rgb | a | paper | 1.00 / 2.00 |" in text
    assert "1.380 (0.010)" in text and "| 50 % |" in text
    assert "4.48 / 1.00" in text  # paper's cylinder normal error beside ours
    assert "evaluations/cylinder/rgb-b/" not in text  # no figures for a failed run
