"""The error a colour polarization mosaic adds: direct captures versus a DoFP sensor's raw image.

Usage::

    .venv/bin/python benchmarks/bench_mosaic.py [--resolution 128] [--presets hemisphere cylinder pyramid]
                                                [--work /tmp/bench_mosaic] [--method coherent]

For each preset one dataset is generated with ``rig.sensor = "dofp-rgb"`` and the preset's
camera noise (reused when already in ``--work``). Three routes reach the RGB reconstruction:

``direct``
    the dataset's per-angle captures (``polarized_rgb.exr``), as the generator writes them;
``raw``
    the generator's ``raw.tiff`` (noise at the raw level, one exposure), through
    ``thinfilm import polarization --layout dofp-rgb`` (bilinear demosaicing, silhouette band
    and saturation marked invalid);
``mosaic``
    a mosaic built from the dataset's own captures (16-bit), through the same import: the
    demosaicing alone, the noise being the direct path's.

Printed per route: coverage of the object, mean and 95th-percentile normal error (degrees) and
mean thickness error (nm) against the ground truth, and the mean difference to the direct
estimate over the pixels both hold; for the images, the median relative difference between
imported and source images over the valid object pixels and the largest difference at the
sampled pixels. As a comparison baseline (not used by the importer), the mosaic route is also
run with a cubic (Keys) interpolation of each plane instead of the bilinear one. Times: import
and reconstruction wall times, the direct reconstruction being the baseline of the ratio.

:func:`mosaic_errors` returns the same figures as a dictionary (for the benchmark report).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np


def _keys_demosaic(raw, pattern):
    """Comparison baseline: Keys cubic (a = −0.5) interpolation of each plane's lattice(s);
    checkerboard planes average their two lattices. Exact at sampled pixels."""
    H, W = raw.shape
    P, Q = pattern.shape

    def weights(n_out, n_sub, offset, stride):
        u = (np.arange(n_out) - offset) / stride
        i0 = np.floor(u).astype(int)
        t = u - i0
        m = np.zeros((n_out, n_sub))

        def k(x):
            x = np.abs(x)
            return np.where(x <= 1, 1.5 * x ** 3 - 2.5 * x ** 2 + 1,
                            np.where(x < 2, -0.5 * x ** 3 + 2.5 * x ** 2 - 4 * x + 2, 0.0))
        for j in range(-1, 3):
            np.add.at(m, (np.arange(n_out), np.clip(i0 + j, 0, n_sub - 1)), k(t - j))
        return m

    out = {a: np.zeros((H, W, 3)) for a in pattern.angles}
    for a in pattern.angles:
        for c in range(3):
            sites = pattern.lattices(c, a)
            est = []
            for r0, c0 in sites:
                sub = raw[r0::P, c0::Q]
                est.append(weights(H, sub.shape[0], r0, P) @ sub @ weights(W, sub.shape[1], c0, Q).T)
            v = np.mean(est, axis=0)
            for r0, c0 in sites:
                v[r0::P, c0::Q] = raw[r0::P, c0::Q]
            out[a][..., c] = v
    return out


def _score(est, gt, direct=None):
    from thinfilm.evaluation import angular_error_deg

    with np.errstate(invalid="ignore", divide="ignore"):
        m = gt["mask"]
        v = est.valid & m
        ne = angular_error_deg(est.normals, gt["normal"])[v]
        out = {"coverage": float(v.sum() / max(m.sum(), 1)), "normal_mean_deg": float(ne.mean()),
               "normal_p95_deg": float(np.percentile(ne, 95)),
               "thickness_mean_nm": float(np.abs(est.thickness_nm - gt["thickness"])[v].mean())}
        if direct is not None:
            both = est.valid & direct.valid
            out["vs_direct_deg"] = float(angular_error_deg(est.normals, direct.normals)[both].mean())
            out["vs_direct_nm"] = float(np.abs(est.thickness_nm - direct.thickness_nm)[both].mean())
    return out


def _image_match(imported, source, gt_mask, sampled_error):
    sel = gt_mask & (imported.valid if imported.valid is not None else True)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.concatenate([np.abs(imported.polarized_rgb[a] - source.polarized_rgb[a])[sel]
                              / source.polarized_rgb[a][sel] for a in source.polarized_rgb])
    rel = rel[np.isfinite(rel)]
    return {"image_median_rel": float(np.median(rel)), "image_max_abs_at_samples": float(sampled_error)}


def mosaic_errors(preset: str = "hemisphere", resolution: int = 128, work=None, method=None,
                  keys_baseline: bool = True) -> dict:
    """Direct versus through-mosaic reconstruction errors of one preset (see the module
    docstring). Returns ``{"direct": {...}, "raw": {...}, "mosaic": {...}[, "mosaic_keys":
    {...}], "timings_s": {...}}``."""
    from thinfilm.cli import main as cli
    from thinfilm.core.io import read_dataset, write_dataset
    from thinfilm.core.mosaic import mosaic_from_images, parse_pattern
    from thinfilm.importers.polarization import import_polarization
    from thinfilm.reconstruct import reconstruct

    work = Path(work or tempfile.mkdtemp(prefix="bench_mosaic_"))
    ds_path = work / f"{preset}_{resolution}_dofp"
    if not (ds_path / "raw.tiff").is_file():
        if cli(["generate", preset, "--out", str(ds_path), "--resolution", str(resolution),
                "--set", "rig.sensor=dofp-rgb"]) != 0:
            raise SystemExit(f"could not generate {preset}")
    src = read_dataset(ds_path, need=("ground_truth", "polarized_rgb"))
    gt = src.ground_truth
    sensor = src.meta["sensor"]
    pattern = parse_pattern(sensor["pattern"])
    film = dict(film_ior=src.meta["film_ior"], substrate_ior=src.meta["substrate_ior"])
    colour = dict(camera=src.meta["camera"], illuminant=src.meta["illuminant"])
    out, times = {}, {}

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        direct = reconstruct("rgb", ds_path, method)[0]
        times["reconstruct_direct"] = time.perf_counter() - t
        out["direct"] = _score(direct, gt)

        t = time.perf_counter()
        raw = import_polarization([ds_path / sensor["file"]], work / f"{preset}_raw_import", "dofp-rgb",
                                  pattern=sensor["pattern"], bit_depth=sensor["bits"],
                                  white_balance=",".join(repr(g) for g in sensor["white_balance"]), **colour, **film)
        times["import_raw"] = time.perf_counter() - t
        t = time.perf_counter()
        est = reconstruct("rgb", raw["path"], method)[0]
        times["reconstruct_raw"] = time.perf_counter() - t
        out["raw"] = _score(est, gt, direct)
        imp = read_dataset(raw["path"])
        out["raw"].update(_image_match(imp, src, gt["mask"], np.nan))

        mosaic = mosaic_from_images(src.polarized_rgb, pattern)
        scale = float(mosaic.max())
        codes = np.rint(np.clip(mosaic, 0, None) / scale * 65535).astype(np.uint16)
        import tifffile

        tifffile.imwrite(work / f"{preset}_mosaic.tif", codes, photometric="minisblack")
        t = time.perf_counter()
        res = import_polarization([work / f"{preset}_mosaic.tif"], work / f"{preset}_mosaic_import", "dofp-rgb",
                                  white_balance=f"{scale!r},{scale!r},{scale!r}", **colour, **film)
        times["import_mosaic"] = time.perf_counter() - t
        imp = read_dataset(res["path"])
        sampled = np.max(np.abs(mosaic_from_images(imp.polarized_rgb, pattern) - codes / 65535 * scale))
        est = reconstruct("rgb", res["path"], method)[0]
        out["mosaic"] = _score(est, gt, direct)
        out["mosaic"].update(_image_match(imp, src, gt["mask"], sampled))

        if keys_baseline:
            keys = _keys_demosaic(codes / 65535 * scale, pattern)
            kpath = work / f"{preset}_mosaic_keys"
            import shutil

            shutil.rmtree(kpath, ignore_errors=True)
            kpath.mkdir(parents=True)
            write_dataset(kpath, dict(imp.meta), polarized_rgb={a: v.astype(np.float32) for a, v in keys.items()},
                          valid=imp.valid, preview=False)
            kimp = read_dataset(kpath)
            est = reconstruct("rgb", kpath, method)[0]
            out["mosaic_keys"] = _score(est, gt, direct)
            out["mosaic_keys"].update(_image_match(kimp, src, gt["mask"], 0.0))
    out["timings_s"] = times
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--presets", nargs="+", default=["hemisphere", "cylinder", "pyramid"])
    ap.add_argument("--work", default="/tmp/bench_mosaic")
    ap.add_argument("--method", default=None, help="RGB method (default: the registry's default)")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON too")
    args = ap.parse_args(argv)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    results = {}
    print(f"resolution {args.resolution}, method {args.method or 'default'}; errors against ground truth, "
          f"and mean difference to the direct estimate")
    print(f"{'preset':11s} {'route':12s} {'cover':>6s} {'normal':>7s} {'p95':>6s} {'thick':>6s} "
          f"{'vs dir':>7s} {'vs dir':>7s} {'img med':>8s}")
    print(f"{'':11s} {'':12s} {'':>6s} {'deg':>7s} {'deg':>6s} {'nm':>6s} {'deg':>7s} {'nm':>7s} {'rel':>8s}")
    for preset in args.presets:
        r = mosaic_errors(preset, args.resolution, work / preset, args.method)
        results[preset] = r
        for route in ("direct", "raw", "mosaic", "mosaic_keys"):
            if route not in r:
                continue
            s = r[route]
            vs = (f"{s['vs_direct_deg']:7.2f} {s['vs_direct_nm']:7.2f}" if "vs_direct_deg" in s else f"{'':7s} {'':7s}")
            img = f"{100 * s['image_median_rel']:7.2f}%" if "image_median_rel" in s else ""
            print(f"{preset:11s} {route:12s} {s['coverage']:6.2f} {s['normal_mean_deg']:7.2f} {s['normal_p95_deg']:6.2f} "
                  f"{s['thickness_mean_nm']:6.2f} {vs} {img}")
        t = r["timings_s"]
        print(f"{'':11s} times: import raw {t['import_raw']:.2f} s, import mosaic {t['import_mosaic']:.2f} s, "
              f"reconstruct direct {t['reconstruct_direct']:.2f} s (baseline), raw "
              f"{t['reconstruct_raw']:.2f} s ({t['reconstruct_raw'] / t['reconstruct_direct']:.2f}x)")
    if args.json:
        print(json.dumps(results, indent=2))
    return results


if __name__ == "__main__":
    main()
