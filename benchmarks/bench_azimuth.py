"""Speed and accuracy of the azimuth's global sign (``reconstruction/azimuth.py``) against a
baseline copy of the module measured in the same run.

Usage::

    .venv/bin/python benchmarks/bench_azimuth.py [--baseline OTHER/reconstruction/azimuth.py]
        [--repeat 3]

The module needs only NumPy and SciPy, so the baseline (another checkout's file, e.g. one
from ``git show REV:reconstruction/azimuth.py > /tmp/azimuth_base.py``) is loaded from its
path into this process and runs on the same fields. Each field is an analytic normal field
whose measured axis and zenith carry noise in the doubled-angle polarization (as the RGB and
spectral fits deliver them), with confidence ``|v| / (25 σ)``:

* ``hemisphere``: 96 px, σ 0.002;
* ``noisy hemisphere``: 109 px (just under the full-resolution limit of 12 000 pixels),
  σ 0.02 and confidence at most 0.4: most pixels are free, many regions, the worst case of
  the free pixels' couplings;
* ``speckled hemisphere``: 109 px, each axis turned by Gaussian noise of 20° and each
  confidence drawn uniformly below 0.4 (independent of the signal, as from a dark,
  unevenly lit capture): hundreds of small regions, the worst case of the free pixels'
  couplings that touch many regions;
* ``low wave`` and ``egg crate``: open sheets of slope 0.2 at 80 px, σ 0.004 and 0.005
  (scored against the truth or its mirror image, which give the same data).

Prints per field the wall time (best of ``--repeat``), the mean normal error and the fraction
of pixels off by more than 10°, and the ratio of the wall times this / baseline.
"""

from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path

import numpy as np


def _load(path):
    spec = importlib.util.spec_from_file_location(f"azimuth_{abs(hash(str(path)))}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _hemisphere(res):
    y, x = np.mgrid[1:-1:res * 1j, -1:1:res * 1j]
    r2 = x * x + y * y
    mask = r2 < 0.97
    n = np.stack([x, y, np.sqrt(np.clip(1 - r2, 0, None))], -1)
    return n, mask


def _wave(res, slope, cross, periods=2.5, angle_deg=20.0):
    y, x = np.mgrid[res // 2:-res // 2:-1, -res // 2:res // 2].astype(float)
    a = np.radians(angle_deg)
    u, v = x * np.cos(a) + y * np.sin(a), -x * np.sin(a) + y * np.cos(a)
    k = 2 * np.pi * periods / res
    gu = -slope * np.sin(k * u) * (np.cos(k * v) if cross else 1.0)
    gv = -slope * np.cos(k * u) * np.sin(k * v) if cross else np.zeros_like(u)
    gx, gy = gu * np.cos(a) - gv * np.sin(a), gu * np.sin(a) + gv * np.cos(a)
    n = np.stack([-gx, -gy, np.ones_like(gx)], -1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True), np.ones(x.shape, dtype=bool)


def fields():
    """(name, normals, mask, σ (None: speckled, see the module docstring), confidence cap,
    mirror-equivalent)."""
    return [("hemisphere", *_hemisphere(96), 0.002, 1.0, False),
            ("noisy hemisphere", *_hemisphere(109), 0.02, 0.4, False),
            ("speckled hemisphere", *_hemisphere(109), None, 0.4, False),
            ("low wave", *_wave(80, 0.2, False), 0.004, 1.0, True),
            ("egg crate", *_wave(80, 0.2, True), 0.005, 1.0, True)]


def measure(module, normals, mask, sigma, cap, seed=0):
    """The module's azimuth from noisy measurements of ``normals``: (seconds, normals)."""
    rng = np.random.default_rng(seed)
    th = np.arccos(np.clip(normals[..., 2], -1, 1))
    phi = np.arctan2(normals[..., 1], normals[..., 0])
    if sigma is None:
        thn = th
        phin = np.mod(phi + np.radians(20.0) * rng.standard_normal(mask.shape), np.pi)
        conf = rng.uniform(0.0, cap, mask.shape)
    else:
        u = np.sin(th) ** 2
        v = np.stack([u * np.cos(2 * phi), u * np.sin(2 * phi)], -1) + sigma * rng.standard_normal(mask.shape + (2,))
        un = np.clip(np.hypot(v[..., 0], v[..., 1]), 0, 1)
        thn = np.arcsin(np.sqrt(un))
        phin = np.mod(0.5 * np.arctan2(v[..., 1], v[..., 0]), np.pi)
        conf = np.clip(un / (25 * sigma), 0, cap)
    t = time.perf_counter()
    az = module.resolve_azimuth_global(np.degrees(phin), np.degrees(thn), mask, conf)
    seconds = time.perf_counter() - t
    a = np.radians(np.nan_to_num(az))
    return seconds, np.stack([np.sin(thn) * np.cos(a), np.sin(thn) * np.sin(a), np.cos(thn)], -1)


def errors(est, normals, mask, mirror):
    def err(truth):
        return np.degrees(np.arccos(np.clip(np.sum(est[mask] * truth[mask], -1), -1, 1)))

    e = err(normals)
    if mirror:
        e2 = err(normals * np.array([-1.0, -1.0, 1.0]))
        e = e2 if e2.mean() < e.mean() else e
    return float(e.mean()), float(np.mean(e > 10.0))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default=None, help="path of another azimuth.py to compare with")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    here = Path(__file__).resolve().parents[1] / "reconstruction" / "azimuth.py"
    modules = [("this", _load(here))]
    if args.baseline:
        modules.append(("baseline", _load(Path(args.baseline))))
    print(f"{'field':20s} {'module':9s} {'pixels':>6s} {'wall s':>7s} {'mean deg':>8s} {'>10 deg':>7s}")
    for _, module in modules:          # first calls import SciPy's graph routines
        measure(module, *_hemisphere(24), 0.002, 1.0)
    for name, normals, mask, sigma, cap, mirror in fields():
        times = {}
        for label, module in modules:
            best, est = min((measure(module, normals, mask, sigma, cap) for _ in range(args.repeat)),
                            key=lambda r: r[0])
            times[label] = best
            mean, off = errors(est, normals, mask, mirror)
            print(f"{name:20s} {label:9s} {int(mask.sum()):6d} {best:7.3f} {mean:8.2f} {off:7.3f}")
        if "baseline" in times:
            print(f"{'':20s} this / baseline wall time: {times['this'] / times['baseline']:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
