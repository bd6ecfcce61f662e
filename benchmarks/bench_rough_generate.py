"""Benchmark: rough-film datasets, their generation time against the smooth film's and their
rendering noise against the camera noise.

Time: a full dataset of a preset (default hemisphere, 128 x 128, 81 bands of 4 nm, 4 polarizer
angles, camera noise) with the film smooth (the baseline, measured in the same run) and rough
(``film.roughness``, the samples per pixel of ``rig.spp``, default "auto"), generated in
alternation after a warm-up; medians of wall and CPU time (all threads of this process) and
the median of the paired ratios.

Noise: for each preset and roughness, the band images I(α) of the hyperspectral camera
rendered with ``--seeds`` render seeds (48 px, bands 480-560 nm); the rendering noise of a
pixel is the standard deviation over the seeds, the camera noise that of the noise model
drawn 16 times on the mean image (each band and angle exposed on its own, as captured).
Printed: the root-mean-square ratio (sqrt of mean render variance / mean camera variance
over object pixels, bands and angles), and the median and 95th percentile of the per-pixel
ratio (with a few seeds the percentiles are widened by the estimate's own scatter).

    python benchmarks/bench_rough_generate.py [--preset hemisphere] [--resolution 128]
        [--alpha 0.1] [--repeats 2] [--noise-presets hemisphere,cylinder,pyramid]
        [--noise-alphas 0.02,0.05,0.1,0.3] [--spp auto,128] [--seeds 8] [--skip-time] [--skip-noise]
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def timed(fn):
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - t0, time.process_time() - c0


def time_generation(args):
    from thinfilm.generators.generate import generate_dataset, rough_spp
    from thinfilm.generators.spec import load_spec

    smooth = load_spec(args.preset, resolution=args.resolution)
    rough = load_spec(args.preset, overrides=[f"film.roughness={args.alpha}"], resolution=args.resolution)
    tmp = Path(tempfile.mkdtemp(prefix="bench_rough_generate_"))
    try:
        for name, alpha in (("smooth", 0.0), ("rough", args.alpha)):  # warm-up: kernels compiled
            generate_dataset(load_spec(args.preset, overrides=[f"film.roughness={alpha}"], resolution=16),
                             tmp / f"warm_{name}", progress=False)
        times = {"smooth": [], "rough": []}
        for i in range(args.repeats):
            for name, spec in (("smooth", smooth), ("rough", rough)):
                out = tmp / f"{name}{i}"
                times[name].append(timed(lambda: generate_dataset(spec, out, progress=False)))
                shutil.rmtree(out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"\n{args.preset} {args.resolution}x{args.resolution}, {smooth.rig.wavelengths.size} bands, "
          f"rough alpha {args.alpha} at {rough_spp(rough)} spp (median of {args.repeats})")
    for name in ("smooth", "rough"):
        wall = statistics.median(t[0] for t in times[name])
        cpu = statistics.median(t[1] for t in times[name])
        print(f"  {name:<7} wall {wall:6.2f} s   CPU {cpu:6.2f} s")
    for which, label in ((0, "wall"), (1, "CPU")):
        a = [t[which] for t in times["rough"]]
        b = [t[which] for t in times["smooth"]]
        print(f"  rough / smooth ({label}): {statistics.median(a) / statistics.median(b):.2f} "
              f"(paired median {statistics.median(x / y for x, y in zip(a, b)):.2f})")


def noise_ratio(preset, alpha, spp, seeds):
    """(rms ratio, median ratio, p95 ratio, spp rendered, seconds per cube)."""
    from thinfilm.core.conventions import malus_intensity
    from thinfilm.generators.generate import simulate
    from thinfilm.generators.noise import apply_camera_noise
    from thinfilm.generators.spec import load_spec

    overrides = [f"film.roughness={alpha}", "rig.wavelengths_nm={start = 480.0, stop = 560.0, step = 4.0}",
                 f"rig.spp={spp}"]
    angles = [0, 45, 90, 135]
    images, mask, rendered, seconds = [], None, None, []
    for seed in range(seeds):
        spec = load_spec(preset, overrides=overrides, resolution=48, seed=seed)
        t0 = time.perf_counter()
        sim = simulate(spec)
        seconds.append(time.perf_counter() - t0)
        mask, rendered = sim["ground_truth"]["mask"], sim["spp"]
        stokes = [sim["stokes_exact"][k] for k in ("S0", "S1", "S2")]
        images.append(np.stack(malus_intensity(*stokes, angles)))
    images = np.stack(images)  # (seed, angle, H, W, band)
    mean = images.mean(axis=0)
    render_var = images.var(axis=0, ddof=1)[:, mask]
    rng = np.random.default_rng(0)
    camera_var = []
    for a in range(len(angles)):
        frames = np.moveaxis(mean[a], -1, 0)
        draws = np.stack([apply_camera_noise(frames, mask, spec.noise.as_dict(), rng) for _ in range(16)])
        camera_var.append(np.moveaxis(draws.var(axis=0, ddof=1), 0, -1)[mask])
    camera_var = np.stack(camera_var)
    per_pixel = np.sqrt(render_var / np.maximum(camera_var, 1e-30))
    return (float(np.sqrt(render_var.mean() / camera_var.mean())), float(np.median(per_pixel)),
            float(np.percentile(per_pixel, 95)), rendered, statistics.median(seconds))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="hemisphere")
    p.add_argument("--resolution", type=int, default=128)
    p.add_argument("--alpha", type=float, default=0.1)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--noise-presets", default="hemisphere,cylinder,pyramid")
    p.add_argument("--noise-alphas", default="0.02,0.05,0.1,0.3")
    p.add_argument("--spp", default="auto", help="comma-separated rig.spp values for the noise table")
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--skip-time", action="store_true")
    p.add_argument("--skip-noise", action="store_true")
    args = p.parse_args(argv)

    import os

    from thinfilm.core.variants import use_variant

    mi = use_variant()
    print(f"cores: {os.cpu_count()}, mitsuba {mi.__version__}")
    if not args.skip_time:
        time_generation(args)
    if not args.skip_noise:
        print(f"\nrendering noise / camera noise of the band images I(α) (48 px, 21 bands, "
              f"{args.seeds} seeds; default camera)")
        print(f"  {'preset':<11} {'alpha':>6} {'spp':>5}   {'rms':>5} {'median':>6} {'p95':>5}   s/cube")
        for preset in args.noise_presets.split(","):
            for alpha in (float(a) for a in args.noise_alphas.split(",")):
                for spp in args.spp.split(","):
                    rms, med, p95, rendered, sec = noise_ratio(preset, alpha, spp, args.seeds)
                    print(f"  {preset:<11} {alpha:6.3f} {rendered:5d}   {rms:5.2f} {med:6.2f} "
                          f"{p95:5.2f}   {sec:6.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
