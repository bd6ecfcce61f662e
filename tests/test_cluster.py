"""A real Dask cluster on localhost: ``dask scheduler`` and two ``dask worker`` processes.

The benchmark run on the cluster (``--scheduler``) scores every task exactly as the same run
in this process, and a sweep of 6 datasets comes out byte-identical, with the same index.
Everything listens on 127.0.0.1 only; the processes are always ended, with bounded waits.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest

from thinfilm import benchmark
from thinfilm.sweep import run_sweep

SWEEP = """
[shape]
kind = { choice = ["hemisphere", "cylinder", "pyramid"] }
[film]
ior = { uniform = [1.30, 1.45] }
[film.thickness]
profile = "uniform"
value = { uniform = [300.0, 700.0] }
[rig]
resolution = 16
wavelengths_nm = { start = 400.0, stop = 720.0, step = 16.0 }
"""


def _stop(procs):
    """Terminate the workers, then the scheduler (workers left without one wait to reconnect);
    kill what has not ended within the bounded wait."""
    for group in (procs[1:], procs[:1]):
        for p in group:
            if p.poll() is None:
                p.terminate()
        deadline = time.monotonic() + 15
        for p in group:
            try:
                p.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=5)


@pytest.fixture(scope="module")
def scheduler_file(tmp_path_factory):
    """Start a scheduler and two single-threaded workers; yield the scheduler file."""
    from distributed import Client

    root = tmp_path_factory.mktemp("cluster")
    sfile = root / "scheduler.json"
    dask = [sys.executable, "-m", "dask"]
    procs = []
    logs = []
    try:
        log = open(root / "scheduler.log", "w")
        logs.append(log)
        procs.append(subprocess.Popen(dask + ["scheduler", "--scheduler-file", str(sfile), "--host", "127.0.0.1",
                                              "--port", "0", "--no-dashboard"],
                                      stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, cwd=root))
        deadline = time.monotonic() + 60
        while not sfile.is_file() and time.monotonic() < deadline and procs[0].poll() is None:
            time.sleep(0.2)
        assert sfile.is_file(), (root / "scheduler.log").read_text()
        for i in range(2):
            log = open(root / f"worker{i}.log", "w")
            logs.append(log)
            procs.append(subprocess.Popen(dask + ["worker", "--scheduler-file", str(sfile), "--nthreads", "1",
                                                  "--host", "127.0.0.1", "--no-dashboard", "--name", f"w{i}"],
                                          stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, cwd=root))
        with Client(scheduler_file=str(sfile), timeout="30s") as client:
            client.wait_for_workers(2, timeout=90)
            info = client.scheduler_info()
            assert all(addr.startswith("tcp://127.0.0.1:") for addr in [info["address"], *info["workers"]])
        yield sfile
    finally:
        _stop(procs)
        for log in logs:
            log.close()


# the presets suite's scenes with 21 point-sampled bands: the same work, an eighth of the renders
PRESETS_FAST = """
name = "presets-fast"
[[scenes]]
name = "hemisphere"
spec = "hemisphere"
overrides = ["rig.wavelengths_nm = { start = 400.0, stop = 720.0, step = 16.0 }", "rig.band_fwhm_nm = 0"]
[[scenes]]
name = "cylinder"
spec = "cylinder"
overrides = ["rig.wavelengths_nm = { start = 400.0, stop = 720.0, step = 16.0 }", "rig.band_fwhm_nm = 0"]
[[scenes]]
name = "pyramid"
spec = "pyramid"
overrides = ["rig.wavelengths_nm = { start = 400.0, stop = 720.0, step = 16.0 }", "rig.band_fwhm_nm = 0"]
kinds = ["rgb"]
"""


@pytest.mark.slow
def test_benchmark_on_a_cluster_scores_as_in_one_process(scheduler_file, tmp_path):
    (tmp_path / "suite.toml").write_text(PRESETS_FAST)
    kwargs = dict(suite=tmp_path / "suite.toml", quick=True, resolution=24, methods=["coherent"], progress=False,
                  figures=False)
    local = benchmark.run_benchmark(tmp_path / "local", workers=0, **kwargs)
    remote = benchmark.run_benchmark(tmp_path / "cluster", scheduler=str(scheduler_file), **kwargs)
    assert remote["execution"]["mode"] == "scheduler" and remote["execution"]["workers"] == 2
    rows_l, rows_r = local["rows"], remote["rows"]
    assert [(r["scene"], r["kind"], r["method"]) for r in rows_r] == [(r["scene"], r["kind"], r["method"])
                                                                        for r in rows_l]
    assert len(rows_l) == 6 and not [r for r in rows_l + rows_r if "error" in r]
    for a, b in zip(rows_l, rows_r):
        assert b["metrics"] == a["metrics"] and b["coverage"] == a["coverage"], (a["scene"], a["method"])
        assert (b["film_ior_estimated"] == a["film_ior_estimated"])
    saved = json.loads((tmp_path / "cluster" / "results.json").read_text())
    assert [r["metrics"] for r in saved["rows"]] == [r["metrics"] for r in rows_l]
    # the same datasets, byte for byte
    for case in ("hemisphere", "cylinder", "pyramid"):
        for name in ("polarized_rgb.exr", "spectral_s.exr", "meta.json"):
            assert ((tmp_path / "cluster" / "datasets" / case / name).read_bytes()
                    == (tmp_path / "local" / "datasets" / case / name).read_bytes())


@pytest.mark.slow
def test_sweep_on_a_cluster_is_byte_identical(scheduler_file, tmp_path):
    (tmp_path / "sweep.toml").write_text(SWEEP)
    local = run_sweep(tmp_path / "sweep.toml", 6, 5, tmp_path / "local", workers=0)
    remote = run_sweep(tmp_path / "sweep.toml", 6, 5, tmp_path / "cluster", scheduler=str(scheduler_file))
    assert remote["execution"]["mode"] == "scheduler"
    assert local["failed"] == remote["failed"] == {} and remote["generated"] == 6

    def files(root):
        return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}

    a, b = files(tmp_path / "local"), files(tmp_path / "cluster")
    assert sorted(a) == sorted(b) and len([k for k in a if k.endswith("meta.json")]) == 6
    assert "index.csv" in a and a["index.csv"].count(b"\n") == 7
    different = [k for k in a if a[k] != b[k]]
    assert not different
