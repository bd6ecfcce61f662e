"""Wall and CPU time of ``thinfilm reconstruct KIND DATASET`` (the whole command), against a
baseline command measured in the same run: another checkout's interpreter (its code on the
same dataset), alternating runs, medians.

Usage::

    .venv/bin/python benchmarks/bench_reconstruct_cli.py --kind spectral --dataset DIR
        [--baseline-python OTHER/.venv/bin/python] [--repeat 5] [--method NAME]

Targets (the issue's, on 2 cores): ``reconstruct spectral`` <= 2 s at 256 x 256 x 81,
``reconstruct rgb`` <= 1 s at 128 x 128.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def run(python, kind, dataset, out, method=None):
    """Wall seconds and CPU seconds (user + system, children) of one command."""
    cmd = [python, "-m", "thinfilm.cli", "reconstruct", kind, str(dataset), "--out", str(out)]
    if method:
        cmd += ["--method", method]
    before = os.times()
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    wall = time.perf_counter() - t0
    after = os.times()
    cpu = (after.children_user - before.children_user) + (after.children_system - before.children_system)
    return wall, cpu


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kind", choices=["rgb", "spectral"], required=True)
    ap.add_argument("--dataset", required=True)
    ap.add_argument("--baseline-python", default=None, help="the baseline checkout's interpreter")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--method", default=None)
    args = ap.parse_args(argv)
    contenders = {"this": sys.executable}
    if args.baseline_python:
        contenders["baseline"] = args.baseline_python
    times = {k: [] for k in contenders}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeat):
            for name, python in contenders.items():
                times[name].append(run(python, args.kind, args.dataset, Path(tmp) / f"{name}{i}", args.method))
    for name, ts in times.items():
        wall = statistics.median(t[0] for t in ts)
        cpu = statistics.median(t[1] for t in ts)
        print(f"{name:8s} reconstruct {args.kind}: median wall {wall:.2f} s, CPU {cpu:.2f} s "
              f"(walls {', '.join(f'{t[0]:.2f}' for t in ts)})")
    if "baseline" in times:
        ratio = statistics.median(t[0] for t in times["this"]) / statistics.median(t[0] for t in times["baseline"])
        ratio_cpu = statistics.median(t[1] for t in times["this"]) / statistics.median(t[1] for t in times["baseline"])
        print(f"ratio this / baseline: wall {ratio:.2f}, CPU {ratio_cpu:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
