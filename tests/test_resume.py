"""Resume after any interruption: a real ``thinfilm benchmark --resume`` (and ``generate --sweep
--resume``) is stopped at a random moment by SIGKILL, SIGTERM, SIGQUIT or SIGHUP, run again with
the same command, and must end with the bytes of a run that was never interrupted.

The kill times are drawn from seeded generators within the length of the uninterrupted run.
A signal the command can catch must end it cleanly (exit status 128 + the signal, one line
``thinfilm: terminated``), leaving no temporary folder, stage folder or lock behind; after
SIGKILL the next run cleans what the killed one left. Files that record timings or absolute
temporary paths (``task.json``, ``results.json``, ``evaluation.json``, ``estimate.json``,
``report.md``, ``report.html``) are compared with those fields left out; every other file byte
for byte.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

FAST = "rig.wavelengths_nm = { start = 400.0, stop = 720.0, step = 16.0 }"
SUITE = "".join(f'[[scenes]]\nname = "{name}"\nspec = "{name}"\nresolution = 16\nkinds = ["rgb"]\n'
                f"overrides = [{json.dumps(FAST)}]\n\n" for name in ("pyramid", "cylinder"))
SWEEP = f"""
[shape]
kind = {{ choice = ["hemisphere", "cylinder"] }}
[film]
ior = {{ uniform = [1.30, 1.50] }}
[rig]
resolution = 16
wavelengths_nm = {{ start = 400.0, stop = 720.0, step = 16.0 }}
"""
# what a temporary of ours, a stage folder or a lock is named like
LEFTOVER = re.compile(r"^\..+\.(tmp|old|stage)-\d+@|\.lock$")
TIMING_KEYS = {"timings_s", "timings", "execution", "resumed", "total"}


# the inputs are the reference's (their paths are recorded in the outputs); the outputs differ
def _benchmark_args(root: Path, out: Path, workers: int = 0) -> list:
    return [sys.executable, "-m", "thinfilm.cli", "benchmark", "--suite", str(root / "suite.toml"), "--methods",
            "coherent", "--no-figures", "--workers", str(workers), "--resume", "--out", str(out)]


def _sweep_args(root: Path, out: Path) -> list:
    return [sys.executable, "-m", "thinfilm.cli", "generate", "--sweep", str(root / "sweep.toml"), "--count", "3",
            "--seed", "5", "--workers", "0", "--resume", "--out", str(out)]


def _run(args, cwd) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=cwd, capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=600)


def _interrupt(args, cwd, delay: float, signum: int):
    """Start ``args``, send ``signum`` after ``delay`` seconds; return (exit status, stderr)."""
    with open(Path(cwd) / "stderr.txt", "w+") as err:
        proc = subprocess.Popen(args, cwd=cwd, stdout=subprocess.DEVNULL, stderr=err, stdin=subprocess.DEVNULL,
                                start_new_session=True)
        try:
            proc.wait(timeout=delay)
        except subprocess.TimeoutExpired:
            proc.send_signal(signum)
        rc = proc.wait(timeout=120)
        err.seek(0)
        return rc, err.read()


def _leftovers(folder: Path) -> list:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if LEFTOVER.search(p.name))


def _strip(value, key=None):
    """A JSON value without its timings, run statistics and absolute (temporary) paths."""
    if isinstance(value, dict):
        return {k: _strip(v, k) for k, v in value.items()
                if k not in TIMING_KEYS and not k.endswith("_s")
                and not (isinstance(v, str) and os.path.isabs(v) and k in ("dataset", "estimate"))}
    if isinstance(value, list):
        return [_strip(v) for v in value]
    return value


def _report_without_timings(text: str) -> list:
    """``report.md`` without its timings: the wall time, the timings section, and the last
    column of the tables whose last column is the reconstruction time."""
    text = re.sub(r"total wall time \d+ s[^.]*\.", "", text.split("## Timings")[0])
    lines, timed = [], False
    for line in text.splitlines():
        if not line.startswith("|"):
            timed = False
        elif not timed and line.endswith("| reconstruct (s) |"):
            timed = True
        elif timed and not line.startswith("|---"):
            line = line.rsplit("|", 2)[0] + "|"
        lines.append(line)
    return lines


def _content(out: Path) -> dict:
    """Every file below ``out``: its bytes, or for the files that record timings, their content
    without them."""
    files = {}
    for p in sorted(out.rglob("*")):
        if p.is_dir():
            files[str(p.relative_to(out)) + "/"] = None
            continue
        data = p.read_bytes()
        if p.suffix == ".json" and p.name in ("task.json", "results.json", "evaluation.json", "estimate.json"):
            data = _strip(json.loads(data))
        elif p.name == "report.md":
            data = _report_without_timings(data.decode())
        elif p.name == "report.html":  # its timings are the elements of class "timing"
            data = re.sub(r'<(td|span) class="timing"[^>]*>.*?</\1>', "", data.decode())
        files[str(p.relative_to(out))] = data
    return files


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """One uninterrupted benchmark and one uninterrupted sweep, and how long each took."""
    root = tmp_path_factory.mktemp("resume")
    (root / "suite.toml").write_text('name = "tiny"\n\n' + SUITE)
    (root / "sweep.toml").write_text(SWEEP)
    took = {}
    for what, args in (("benchmark", _benchmark_args(root, root / "benchmark")),
                       ("sweep", _sweep_args(root, root / "sweep"))):
        t0 = time.monotonic()
        r = _run(args, root)
        took[what] = time.monotonic() - t0
        assert r.returncode == 0, r.stderr
    return root, took


def _check_resumed(reference, out: Path, args, signum: int, rc: int, err: str, what: str):
    root, _ = reference
    assert rc != 0, "the run ended before the signal came"
    if signum == signal.SIGKILL:
        assert rc == -signum, err
    else:  # caught: a clean end, nothing left behind
        assert rc == 128 + signum, err
        assert err.strip().splitlines()[-1:] == ["thinfilm: terminated"], err
        assert not _leftovers(out.parent), _leftovers(out.parent)
    assert "leaked" not in err, err
    finished = set()
    if what == "benchmark" and out.is_dir():
        finished = {str(p.parent.relative_to(out)) for p in out.glob("tasks/*/*/task.json")}
    again = _run(args, out.parent)
    assert again.returncode == 0, again.stderr
    assert "leaked" not in again.stderr, again.stderr
    assert not _leftovers(out.parent), _leftovers(out.parent)
    assert _content(out) == _content(root / what)
    if what == "benchmark":  # the tasks finished before the interruption were kept, not run again
        rows = json.loads((out / "results.json").read_text())["rows"]
        assert {r["task"] for r in rows if r.get("resumed")} == finished


@pytest.mark.slow
@pytest.mark.parametrize("seed, signame", [(0, "SIGKILL"), (1, "SIGTERM"), (2, "SIGQUIT")])
def test_benchmark_resumes_after_a_signal_at_a_random_moment(reference, tmp_path, seed, signame):
    root, took = reference
    delay = float(np.random.default_rng(seed).uniform(0.1, 0.95) * took["benchmark"])
    out = tmp_path / "benchmark"
    args = _benchmark_args(root, out)
    signum = getattr(signal, signame)
    rc, err = _interrupt(args, tmp_path, delay, signum)
    _check_resumed(reference, out, args, signum, rc, err, "benchmark")


@pytest.mark.slow
def test_benchmark_on_worker_processes_ends_cleanly_on_sighup_and_resumes(reference, tmp_path):
    root, took = reference
    out = tmp_path / "benchmark"
    args = _benchmark_args(root, out, workers=2)
    delay = float(np.random.default_rng(3).uniform(0.3, 0.95) * took["benchmark"])
    rc, err = _interrupt(args, tmp_path, delay, signal.SIGHUP)
    _check_resumed(reference, out, args, signal.SIGHUP, rc, err, "benchmark")


@pytest.mark.slow
def test_sweep_resumes_after_sigkill_at_a_random_moment(reference, tmp_path):
    root, took = reference
    out = tmp_path / "sweep"
    args = _sweep_args(root, out)
    delay = float(np.random.default_rng(4).uniform(0.1, 0.95) * took["sweep"])
    rc, err = _interrupt(args, tmp_path, delay, signal.SIGKILL)
    _check_resumed(reference, out, args, signal.SIGKILL, rc, err, "sweep")
