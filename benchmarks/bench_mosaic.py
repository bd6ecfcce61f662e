"""The error a colour polarization mosaic adds: direct captures versus a DoFP sensor's raw image.

Usage::

    .venv/bin/python benchmarks/bench_mosaic.py [--resolution 64] [--raw-per-pixel 4 2]
                                                [--presets hemisphere cylinder pyramid]
                                                [--work /tmp/bench_mosaic] [--method coherent]

For each preset and each ``k`` of ``--raw-per-pixel`` one dataset is generated at ``k`` times
``--resolution`` with ``rig.sensor = "dofp-rgb"`` and the preset's camera noise (reused when
already in ``--work``): ``k × k`` raw pixels per pixel of the reconstruction. ``k = 4``: one
whole period of the Sony IMX250MYR pattern per pixel; ``k = 2``: one 2 × 2 polarizer block of
one colour per pixel, the resolution a real sensor's polarization images are used at; ``k =
1``: the mosaic at the reconstruction's own resolution. Every route's images are binned ``k ×
k`` (the mean of the block; a binned pixel is valid when its whole block is) and
reconstructed with the RGB method at ``--resolution``:

``direct``
    the dataset's per-angle captures (``polarized_rgb.exr``), as the generator writes them;
``raw``
    the generator's ``raw.tiff`` (noise at the raw level, one exposure), through
    ``thinfilm import polarization --layout dofp-rgb`` (default ``--demosaic residual``, the
    object's outermost 3 pixels invalid);
``mosaic``
    a mosaic built from the dataset's own captures (16-bit), through the same import: the
    demosaicing alone, the noise being the direct path's;
``mosaic_edges_kept``
    the same with ``--edge-margin 0``: every pixel at the silhouette kept;
``mosaic_bilinear``
    the same mosaic with ``--demosaic bilinear`` (the silhouette band marked invalid), for
    comparison.

The ground truth is binned likewise (mask: the whole block on the object; normal: the
normalized mean; thickness: the mean). Printed per route: coverage of the object, mean and
95th-percentile normal error (degrees) and mean thickness error (nm) against the ground
truth, and the mean difference to the direct estimate over the pixels both hold; for the
images, the median relative difference between the route's and the direct images over the
valid object pixels. Times: import and reconstruction wall times, the direct reconstruction
being the baseline of the ratio.

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


def _score(est, gt, direct=None):
    from scipy import ndimage

    from thinfilm.evaluation import angular_error_deg

    with np.errstate(invalid="ignore", divide="ignore"):
        m = gt["mask"]
        v = est.valid & m
        ne = angular_error_deg(est.normals, gt["normal"])[v]
        out = {"coverage": float(v.sum() / max(m.sum(), 1)), "normal_mean_deg": float(ne.mean()),
               "normal_p95_deg": float(np.percentile(ne, 95)),
               "thickness_mean_nm": float(np.abs(est.thickness_nm - gt["thickness"])[v].mean())}
        # the same away from the silhouette: pixels 2 or more pixels inside the object
        inner = v & ndimage.binary_erosion(m, np.ones((3, 3), bool), iterations=2)
        out["inner_share"] = float(inner.sum() / max(v.sum(), 1))
        out["normal_mean_inner_deg"] = float(angular_error_deg(est.normals, gt["normal"])[inner].mean())
        out["thickness_mean_inner_nm"] = float(np.abs(est.thickness_nm - gt["thickness"])[inner].mean())
        if direct is not None:
            both = est.valid & direct.valid
            out["vs_direct_deg"] = float(angular_error_deg(est.normals, direct.normals)[both].mean())
            out["vs_direct_nm"] = float(np.abs(est.thickness_nm - direct.thickness_nm)[both].mean())
    return out


def _image_match(route, direct, gt_mask, valid):
    sel = gt_mask & valid
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.concatenate([np.abs(route[a] - direct[a])[sel] / direct[a][sel] for a in direct])
    rel = rel[np.isfinite(rel)]
    return {"image_median_rel": float(np.median(rel)) if rel.size else float("nan")}


def _bin(x, k):
    """Mean of each k x k block of (H, W, ...) (H, W multiples of k)."""
    if k == 1:
        return np.asarray(x, dtype=np.float64)
    h, w = x.shape[:2]
    return np.asarray(x, dtype=np.float64).reshape(h // k, k, w // k, k, *x.shape[2:]).mean(axis=(1, 3))


def _bin_all(mask, k):
    return _bin(np.asarray(mask, dtype=np.float64), k) > 1.0 - 1e-9


def _binned_dataset(path, meta, images, valid, k):
    """Write a dataset folder of binned images (reconstruction input) and return its path."""
    import shutil

    from thinfilm.core.io import write_dataset

    shutil.rmtree(path, ignore_errors=True)
    path.mkdir(parents=True)
    meta = {key: v for key, v in meta.items() if key not in ("sensor",)}
    if isinstance(meta.get("projection"), dict) and "pixel_size" in meta["projection"]:
        meta["projection"] = dict(meta["projection"], pixel_size=meta["projection"]["pixel_size"] * k)
    h, w = next(iter(images.values())).shape[:2]
    meta["resolution"] = max(h, w) // k
    write_dataset(path, meta, polarized_rgb={a: _bin(v, k).astype(np.float32) for a, v in images.items()},
                  valid=None if valid is None else _bin_all(valid, k), preview=False)
    return path


def mosaic_errors(preset: str = "hemisphere", resolution: int = 64, work=None, method=None, raw_per_pixel: int = 4) -> dict:
    """Direct versus through-mosaic reconstruction errors of one preset with ``raw_per_pixel``
    raw pixels per reconstructed pixel along each axis (see the module docstring). Returns
    ``{"direct": {...}, "raw": {...}, "mosaic": {...}, "mosaic_bilinear": {...},
    "timings_s": {...}}``."""
    from thinfilm.cli import main as cli
    from thinfilm.core.io import read_dataset
    from thinfilm.core.mosaic import mosaic_from_images
    from thinfilm.importers.polarization import import_polarization
    from thinfilm.reconstruct import reconstruct

    k = int(raw_per_pixel)
    work = Path(work or tempfile.mkdtemp(prefix="bench_mosaic_"))
    work.mkdir(parents=True, exist_ok=True)
    ds_path = work / f"{preset}_{k * resolution}"
    if not (ds_path / "raw.tiff").is_file():
        if cli(["generate", preset, "--out", str(ds_path), "--resolution", str(k * resolution),
                "--set", "rig.sensor=dofp-rgb"]) != 0:
            raise SystemExit(f"could not generate {preset}")
    src = read_dataset(ds_path, need=("ground_truth", "polarized_rgb"))
    g = src.ground_truth
    n = _bin(g["normal"], k)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    gt = {"mask": _bin_all(g["mask"], k), "normal": n, "thickness": _bin(g["thickness"], k)}
    sensor = src.meta["sensor"]
    film = dict(film_ior=src.meta["film_ior"], substrate_ior=src.meta["substrate_ior"])
    colour = dict(camera=src.meta["camera"], illuminant=src.meta["illuminant"])
    tag = f"{preset}_{resolution}_k{k}"
    out, times = {}, {}

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        direct_images = {a: _bin(v, k) for a, v in src.polarized_rgb.items()}
        dpath = _binned_dataset(work / f"{tag}_direct", src.meta, src.polarized_rgb, None, k)
        t = time.perf_counter()
        direct = reconstruct("rgb", dpath, method)[0]
        times["reconstruct_direct"] = time.perf_counter() - t
        out["direct"] = _score(direct, gt)

        def route(name, files, demosaic, **kw):
            t = time.perf_counter()
            res = import_polarization(files, work / f"{tag}_{name}_import", "dofp-rgb", demosaic=demosaic,
                                      **kw, **colour, **film)
            times[f"import_{name}"] = time.perf_counter() - t
            imp = read_dataset(res["path"])
            valid = imp.valid if imp.valid is not None else np.ones(imp.shape, dtype=bool)
            rpath = _binned_dataset(work / f"{tag}_{name}", src.meta, imp.polarized_rgb, valid, k)
            t = time.perf_counter()
            est = reconstruct("rgb", rpath, method)[0]
            times[f"reconstruct_{name}"] = time.perf_counter() - t
            out[name] = _score(est, gt, direct)
            out[name].update(_image_match({a: _bin(v, k) for a, v in imp.polarized_rgb.items()}, direct_images,
                                          gt["mask"], _bin_all(valid, k)))

        route("raw", [ds_path / sensor["file"]], "residual", pattern=sensor["pattern"], bit_depth=sensor["bits"],
              white_balance=",".join(repr(g) for g in sensor["white_balance"]))
        mosaic = mosaic_from_images(src.polarized_rgb, parse_pattern_of(sensor))
        scale = float(mosaic.max())
        codes = np.rint(np.clip(mosaic, 0, None) / scale * 65535).astype(np.uint16)
        import tifffile

        tifffile.imwrite(work / f"{tag}_mosaic.tif", codes, photometric="minisblack")
        wb = f"{scale!r},{scale!r},{scale!r}"
        route("mosaic", [work / f"{tag}_mosaic.tif"], "residual", pattern=sensor["pattern"], white_balance=wb)
        route("mosaic_edges_kept", [work / f"{tag}_mosaic.tif"], "residual", pattern=sensor["pattern"],
              white_balance=wb, edge_margin=0)
        route("mosaic_bilinear", [work / f"{tag}_mosaic.tif"], "bilinear", pattern=sensor["pattern"],
              white_balance=wb)
    out["timings_s"] = times
    return out


def parse_pattern_of(sensor):
    from thinfilm.core.mosaic import parse_pattern

    return parse_pattern(sensor["pattern"])


ROUTES = ("direct", "raw", "mosaic", "mosaic_edges_kept", "mosaic_bilinear")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--raw-per-pixel", type=int, nargs="+", default=[4, 2], choices=(1, 2, 4))
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
    print(f"{'preset':11s} {'k':>2s} {'route':16s} {'cover':>6s} {'normal':>7s} {'p95':>6s} {'thick':>6s} "
          f"{'vs dir':>7s} {'vs dir':>7s} {'img med':>8s} {'inner:':>7s} {'normal':>7s} {'thick':>6s}")
    print(f"{'':11s} {'':>2s} {'':16s} {'':>6s} {'deg':>7s} {'deg':>6s} {'nm':>6s} {'deg':>7s} {'nm':>7s} {'rel':>8s} "
          f"{'share':>7s} {'deg':>7s} {'nm':>6s}")
    for preset in args.presets:
        for k in args.raw_per_pixel:
            r = mosaic_errors(preset, args.resolution, work, args.method, k)
            results[f"{preset}_k{k}"] = r
            for name in ROUTES:
                s = r[name]
                vs = (f"{s['vs_direct_deg']:7.2f} {s['vs_direct_nm']:7.2f}" if "vs_direct_deg" in s
                      else f"{'':7s} {'':7s}")
                img = f"{100 * s['image_median_rel']:7.2f}%" if "image_median_rel" in s else ""
                img = img or f"{'':8s}"
                print(f"{preset:11s} {k:2d} {name:16s} {s['coverage']:6.3f} {s['normal_mean_deg']:7.2f} "
                      f"{s['normal_p95_deg']:6.2f} {s['thickness_mean_nm']:6.2f} {vs} {img} {s['inner_share']:7.2f} "
                      f"{s['normal_mean_inner_deg']:7.2f} {s['thickness_mean_inner_nm']:6.2f}", flush=True)
            t = r["timings_s"]
            print(f"{'':11s} {'':2s} times: import raw {t['import_raw']:.2f} s, mosaic {t['import_mosaic']:.2f} s "
                  f"(bilinear {t['import_mosaic_bilinear']:.2f} s); reconstruct direct {t['reconstruct_direct']:.2f} s "
                  f"(baseline), raw {t['reconstruct_raw']:.2f} s "
                  f"({t['reconstruct_raw'] / t['reconstruct_direct']:.2f}x)", flush=True)
    if args.json:
        print(json.dumps(results, indent=2))
    return results


if __name__ == "__main__":
    main()
