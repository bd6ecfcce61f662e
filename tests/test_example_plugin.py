"""The third-party estimator package ``examples/estimator_plugin`` (``thinfilm-example-estimator``).

Installed with pip, it is listed by ``thinfilm methods``, run by ``reconstruct rgb --method
example-flat`` and scored by ``benchmark --suite presets --quick --methods example-flat,coherent``,
all through the entry-point group ``thinfilm.estimators``. ``scripts/test.sh`` (CI) installs it
into the environment; when it is not installed there, this module installs it with pip into a
temporary folder put on the commands' ``PYTHONPATH``.
"""

from __future__ import annotations

import json
import re
import os
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "examples" / "estimator_plugin"
DIST = "thinfilm-example-estimator"


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    """Environment of the commands, with the package installed."""
    env = dict(os.environ)
    try:
        metadata.distribution(DIST)
    except metadata.PackageNotFoundError:
        target = tmp_path_factory.mktemp("site")
        r = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--disable-pip-version-check",
                            "--no-deps", "--target", str(target), str(PACKAGE)], capture_output=True, text=True)
        assert r.returncode == 0, f"pip could not install {PACKAGE}: {r.stderr[-2000:]}"
        env["PYTHONPATH"] = os.pathsep.join([str(target), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def _thinfilm(env, *args, cwd=None):
    return subprocess.run([sys.executable, "-m", "thinfilm.cli", *args], env=env, cwd=cwd, capture_output=True,
                          text=True, stdin=subprocess.DEVNULL)


def test_methods_lists_it_with_its_distribution(env):
    r = _thinfilm(env, "methods", "--json")
    assert r.returncode == 0, r.stderr
    found = {m["name"]: m for m in map(json.loads, r.stdout.splitlines())}
    flat = found["example-flat"]
    assert (flat["kind"], flat["role"], flat["source"]) == ("rgb", "other", DIST)
    assert flat["needs"] == ["polarized_rgb"]
    assert found["coherent"]["source"] == "thinfilm"
    assert "warning" not in r.stderr


@pytest.mark.slow
def test_reconstruct_and_benchmark_run_it(env, tmp_path):
    from thinfilm.core.io import read_estimate

    r = _thinfilm(env, "generate", "cylinder", "--resolution", "24", "--out", str(tmp_path / "ds"))
    assert r.returncode == 0, r.stderr
    r = _thinfilm(env, "reconstruct", "rgb", str(tmp_path / "ds"), "--method", "example-flat",
                  "--thickness-range", "300", "500", "--out", str(tmp_path / "est"))
    assert r.returncode == 0, r.stderr
    assert "method example-flat" in r.stdout
    est = read_estimate(tmp_path / "est")
    assert est.valid.any() and (est.normals[est.valid] == [0.0, 0.0, 1.0]).all()
    assert (est.thickness_nm[est.valid] == 400.0).all()

    out = tmp_path / "bench"
    # the presets suite, the example method beside the default, at 32 px (the quick run's
    # 128 px take a minute on 2 cores)
    r = _thinfilm(env, "benchmark", "--suite", "presets", "--quick", "--methods", "example-flat,coherent",
                  "--resolution", "32", "--out", str(out))
    assert r.returncode == 0, r.stdout + r.stderr
    results = json.loads((out / "results.json").read_text())
    assert results["execution"]["mode"] == "local-cluster"
    rows = {(x["scene"], x["method"]): x for x in results["rows"]}
    presets = ("hemisphere", "cylinder", "pyramid")
    rough = [f"{p}-rough-{a}" for p in presets for a in ("0.02", "0.05", "0.1")]
    expected = {(s, m) for s in presets + tuple(rough) for m in ("ground truth", "example-flat", "coherent")}
    expected |= {(s, f"{m} (mosaic)") for s in presets for m in ("example-flat", "coherent")}
    assert set(rows) == expected
    assert all(x["status"] == "ok" for x in results["rows"]), [x.get("error") for x in results["rows"]]
    for scene in ("hemisphere", "cylinder", "pyramid"):
        flat, coherent = rows[(scene, "example-flat")], rows[(scene, "coherent")]
        assert flat["source"] == DIST and flat["metrics"]["normal_error_deg"]["mean"] > 10.0
        assert coherent["metrics"]["normal_error_deg"]["mean"] < flat["metrics"]["normal_error_deg"]["mean"]
        assert all(x["scene"] and x.get("resumed") is None for x in (flat, coherent))
    board = (out / "report.md").read_text()
    ranks = {m: int(r) for r, m in re.findall(r"^\| (\d+) \| ([^|]+?) \|", board, flags=re.M)}
    assert ranks["coherent"] < ranks["example-flat"] and ranks["coherent (mosaic)"] < ranks["example-flat"]
    assert "| example-flat | other | thinfilm-example-estimator |" in board
