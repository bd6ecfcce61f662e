"""Benchmark: time to generate a full dataset (default 256 x 256, 81 bands at 4 nm, 4 polarizer
angles, camera noise) with the share spent rendering versus writing.

Baseline measured in the same run: the same renders point-sampled (one render per band,
``band_fwhm_nm = 0``), to show what band integration costs.

Usage::

    python benchmarks/bench_generate.py [--preset hemisphere] [--resolution 256] [--repeat 2]

Target (issue 3): <= 15 s per 256 x 256 dataset on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="all", help="hemisphere, cylinder, pyramid or all")
    p.add_argument("--resolution", type=int, default=256)
    p.add_argument("--repeat", type=int, default=2, help="runs per preset; the best is reported")
    args = p.parse_args(argv)

    from thinfilm.core.variants import use_variant
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.core.bands import passband_quadrature
    from thinfilm.generators.render import render_stokes_cube
    from thinfilm.generators.scene import build_scene_dict
    from thinfilm.generators.spec import load_spec

    mi = use_variant()

    presets = ["hemisphere", "cylinder", "pyramid"] if args.preset == "all" else [args.preset]
    print(f"cores: {os.cpu_count()}, resolution {args.resolution}, mitsuba {mi.__version__}")
    tmp = Path(tempfile.mkdtemp(prefix="bench_generate_"))
    try:
        # warm-up: compiles and caches the kernels
        generate_dataset(load_spec(presets[0], resolution=32), tmp / "warm", progress=False)
        for preset in presets:
            spec = load_spec(preset, resolution=args.resolution)
            best = None
            for i in range(args.repeat):
                t0 = time.perf_counter()
                t = generate_dataset(spec, tmp / f"{preset}{i}", progress=False)
                total = time.perf_counter() - t0
                if best is None or total < best[0]:
                    best = (total, t)
                shutil.rmtree(tmp / f"{preset}{i}")
            total, t = best
            wl = spec.rig.wavelengths
            sub, _ = passband_quadrature(wl, spec.rig.band_fwhm_nm, spec.rig.passband)
            # baseline: point-sampled bands, same scene
            scene = mi.load_dict(build_scene_dict(spec)[0])
            t0 = time.perf_counter()
            render_stokes_cube(scene, wl, 0.0)
            point = time.perf_counter() - t0
            print(f"\n{preset}: {total:.2f} s total (target <= 15 s: {'met' if total <= 15 else 'MISSED'})")
            for key in ("scene", "render", "captures", "write"):
                print(f"  {key:<9} {t[key]:6.2f} s  {100 * t[key] / total:5.1f} %")
            print(f"  rendering {wl.size} bands as {sub.size} sub-wavelength renders "
                  f"({1000 * t['render'] / sub.size:.1f} ms each)")
            print(f"  baseline, point-sampled bands ({wl.size} renders): {point:.2f} s; "
                  f"band integration costs x{t['render'] / point:.2f}")
            print(f"  rendering / writing = {t['render'] / t['write']:.2f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
