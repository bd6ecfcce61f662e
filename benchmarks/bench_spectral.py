"""Speed of ``thinfilm reconstruct spectral`` (default method) on a 256×256×81-band capture,
against the paper's full per-pixel (n2, m) search (Eqs. 28–30) measured in the same run.

Usage::

    python benchmarks/bench_spectral.py [--dataset DIR] [--resolution 256] [--preset hemisphere]

Without ``--dataset`` the preset is generated into a temporary folder first (not timed).
Prints absolute wall times and the ratio; the target is <= 2 s for the whole command on 2 cores
(``benchmarks/bench_reconstruct_cli.py`` measures it against another checkout in the same run).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _generate(preset, resolution, out):
    from thinfilm.core.variants import use_variant
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec

    use_variant()
    generate_dataset(load_spec(preset, resolution=resolution), out, progress=False)


def _cli(dataset, out, method):
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "thinfilm.cli", "reconstruct", "spectral", str(dataset),
                    "--out", str(out), "--method", method], check=True)
    return time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default=None)
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--preset", default="hemisphere")
    args = ap.parse_args(argv)

    from thinfilm.core import registry
    from thinfilm.core.io import read_dataset
    from thinfilm.reconstruction import spectral_model as sm
    from thinfilm.reconstruction.peaks import find_peaks
    from thinfilm.reconstruction.spectral_checks import object_mask
    from thinfilm.reconstruction.spectral_paper import kobayashi_search

    default, paper = registry.get("spectral"), registry.get("spectral", "paper")

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        dataset = Path(args.dataset) if args.dataset else tmp / "ds"
        if not args.dataset:
            _generate(args.preset, args.resolution, dataset)
        ds = read_dataset(dataset, need=("spectral_s",))
        h, w, b = ds.spectral_s.shape
        print(f"dataset: {dataset} ({h}x{w}, {b} bands); drjit backend: {sm.drjit_available()}")

        t_default = _cli(dataset, tmp / "est_default", default.name)
        print(f"reconstruct spectral --method {default.name}: {t_default:.2f} s wall (whole command)")
        stages = json.loads((tmp / "est_default" / "estimate.json").read_text()).get("timings_s", {})
        print("  stages (s): " + ", ".join(f"{k} {v:.2f}" for k, v in stages.items()))

        # the paper's full search on every object pixel, same machine, same run
        mask = object_mask(ds.spectral_s)
        spectra = ds.spectral_s[mask].astype(np.float64)
        pk = find_peaks(spectra, ds.wavelengths_nm)
        n3 = ds.film().effective_substrate_index()  # a number also for a named substrate
        theta = sm.angle_from_peak(pk.value, n3)
        t0 = time.perf_counter()
        kobayashi_search(spectra, theta, pk.wavelength_nm, n3, ds.wavelengths_nm)
        t_search = time.perf_counter() - t0
        print(f"paper's full (n2, m) search alone, {int(np.isfinite(theta).sum())} pixels: {t_search:.2f} s")

        t_pub = _cli(dataset, tmp / "est_paper", paper.name)
        print(f"reconstruct spectral --method {paper.name}: {t_pub:.2f} s wall (whole command)")
        print(f"ratio default / paper's full search: {t_default / t_search:.2f}")
        print(f"ratio default / published method (whole command): {t_default / t_pub:.2f}")
        print(f"target <= 2 s: {'met' if t_default <= 2 else 'NOT met'}")


if __name__ == "__main__":
    main()
