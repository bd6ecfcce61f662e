"""Random but plausible scenes, reconstructed by the default methods and scored at fixed bars.

Usage::

    .venv/bin/python benchmarks/sweep_random_scenes.py [--seed 1] [--count 16] [--resolution 96]
        [--work /tmp/sweep] [--hard] [--kinds rgb spectral] [--methods NAME ...] [--no-generate]

Each scene is drawn from the sweep seed (a different seed, a different set of scenes):

* shape: hemisphere, cylinder, pyramid (height 0.3-1.5 on a base of 2), capsule, spherical
  cap (height 0.2-1.3 of the radius), ellipsoid, torus (tilted 0-55 deg), wavy open sheet
  (with ``--hard``: also groups of two or three objects);
* film: a constant index 1.30-1.50, or dispersive MgF2 or SiO2, on a substrate of index
  1.48-1.70 (with ``--hard``: also films of index 1.8-2.4, above the substrate's), thickness
  uniform, linear or radial within 280-760 nm;
* rig: Nikon 5100 or Sigma SDMerill camera; D65, D50 or A light; 10- or 12-bit camera noise.

Every scene is generated at ``--resolution`` px (kept in ``--work``, reused on a second run),
reconstructed by each method (the kind's default unless ``--methods``), and scored against
the ground truth (the definitions of :func:`thinfilm.evaluation.geometry_error_maps`, no
re-rendering) at these bars:

* spectral: coverage >= 90 %, normal error mean <= 3 deg and p95 <= 8 deg, thickness error
  mean <= 8 nm, film index within 0.015;
* rgb: normal error mean <= 4 deg and p95 <= 10 deg, thickness error mean <= 15 nm.

An open sheet and its mirror image ``z -> -z`` give the same captures (no occluding contour
tells them apart; a test shows it), so a sheet's normals are scored against the truth and
against its mirror image, and the better counts; the line ``(mirror)`` says so, and the pass
counts are printed both ways.

Datasets may be scored by another checkout's interpreter (``--no-generate``: only the
reconstruction and scoring run; it uses only APIs older than this script), which gives the
baseline on the same scenes.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
from pathlib import Path

import numpy as np

BARS = {
    "spectral": {"coverage": 0.90, "normal_mean": 3.0, "normal_p95": 8.0, "thickness_mean": 8.0,
                 "film_ior_error": 0.015},
    "rgb": {"normal_mean": 4.0, "normal_p95": 10.0, "thickness_mean": 15.0},
}
SHAPES = ("hemisphere", "cylinder", "pyramid", "capsule", "cap", "ellipsoid", "torus", "sheet")


def _shape(rng, kind):
    u = rng.uniform
    if kind == "hemisphere":
        return {"kind": "hemisphere", "radius": 1.0}
    if kind == "cylinder":
        return {"kind": "cylinder", "radius": 1.0, "length": float(u(1.5, 3.0))}
    if kind == "pyramid":
        return {"kind": "pyramid", "base": 2.0, "height": float(u(0.3, 1.5))}
    if kind == "capsule":
        return {"kind": "capsule", "radius": 0.5, "length": float(u(0.5, 2.0)),
                "rotate_deg": [float(u(-30, 30)), 0.0, float(u(0, 180))]}
    if kind == "cap":
        return {"kind": "cap", "radius": 1.0, "height": float(u(0.2, 1.3))}
    if kind == "ellipsoid":
        return {"kind": "ellipsoid", "semi_axes": [float(u(0.6, 1.2)), float(u(0.6, 1.2)), float(u(0.3, 1.0))],
                "rotate_deg": [float(u(-40, 40)), float(u(-40, 40)), float(u(0, 180))]}
    if kind == "torus":
        return {"kind": "torus", "major_radius": 1.0, "minor_radius": float(u(0.25, 0.5)),
                "rotate_deg": [float(u(0, 55)), 0.0, float(u(0, 180))]}
    if kind == "sheet":
        lam = float(u(0.6, 1.5))
        slope = float(u(0.15, 0.6))
        return {"kind": "sheet", "size": 2.0, "wavelength": lam, "amplitude": slope * lam / (2 * np.pi),
                "cross": bool(rng.random() < 0.5), "direction_deg": float(u(0, 180)),
                "phase_deg": float(u(0, 360))}
    if kind == "group":
        count = int(rng.integers(2, 4))
        parts = []
        for i in range(count):
            sub = _shape(rng, str(rng.choice(["hemisphere", "capsule", "ellipsoid", "torus", "cap"])))
            scale = 0.45
            for key in ("radius", "major_radius", "minor_radius", "length"):
                if key in sub:
                    sub[key] *= scale
            if "semi_axes" in sub:
                sub["semi_axes"] = [a * scale for a in sub["semi_axes"]]
            angle = 2 * np.pi * i / count + float(u(0, 1))
            sub["offset"] = [1.1 * np.cos(angle), 1.1 * np.sin(angle), 0.0]
            parts.append(sub)
        return {"kind": "group", "parts": parts}
    raise ValueError(kind)


def _thickness(rng):
    u = rng.uniform
    profile = str(rng.choice(["uniform", "linear", "radial"]))
    if profile == "uniform":
        return {"profile": "uniform", "value": float(u(300, 700))}
    a, b = float(u(280, 760)), float(u(280, 760))
    if profile == "linear":
        return {"profile": "linear", "start": a, "end": b, "axis": str(rng.choice(["x", "y"]))}
    return {"profile": "radial", "center": a, "edge": b, "radius": 0.0}


def random_spec(rng, hard: bool = False) -> dict:
    """One random scene spec (a dictionary for :func:`thinfilm.generators.spec.load_spec`)."""
    kinds = SHAPES + (("group",) if hard else ())
    kind = str(rng.choice(kinds))
    n3 = float(np.round(rng.uniform(1.48, 1.70), 3))
    films = ["constant", "MgF2", "SiO2"] + (["high"] if hard else [])
    film = str(rng.choice(films))
    if film == "constant":
        ior = float(np.round(rng.uniform(1.30, 1.50), 3))
    elif film == "high":
        ior = float(np.round(rng.uniform(1.8, 2.4), 3))
    else:
        ior = film
    return {
        "seed": int(rng.integers(0, 2 ** 31)),
        "shape": _shape(rng, kind),
        "film": {"ior": ior, "thickness": _thickness(rng)},
        "substrate": {"ior": n3},
        "rig": {"camera": str(rng.choice(["Nikon 5100 (NPL)", "Sigma SDMerill (NPL)"])),
                "illuminant": str(rng.choice(["D65", "D50", "A"]))},
        "noise": {"bits": int(rng.choice([10, 12]))},
    }


def describe(spec: dict) -> str:
    s = spec["shape"]
    extra = {"pyramid": lambda: f"h{s['height']:.2f}", "cap": lambda: f"h{s['height']:.2f}",
             "torus": lambda: f"tilt{s['rotate_deg'][0]:.0f}",
             "sheet": lambda: f"{'x' if s['cross'] else '-'}slope{2 * np.pi * s['amplitude'] / s['wavelength']:.2f}",
             "group": lambda: "+".join(p["kind"] for p in s["parts"])}.get(s["kind"], lambda: "")()
    f = spec["film"]
    n2 = f["ior"] if isinstance(f["ior"], str) else f"{f['ior']:.3f}"
    cam = spec["rig"]["camera"].split()[0]
    return (f"{s['kind']}{(' ' + extra) if extra else ''} | {n2} on {spec['substrate']['ior']:.3f}, "
            f"{f['thickness']['profile']} | {cam} {spec['rig']['illuminant']} {spec['noise']['bits']}b")


def score(dataset: Path, estimate, kind: str, mirror_equivalent: bool = False) -> dict:
    """Scores of an estimate against the dataset's ground truth (no re-rendering).

    ``mirror_equivalent``: the scene's mirror image ``z -> -z`` gives the same captures (an
    open sheet under the orthographic camera and the dome,
    ``tests/test_robust_reconstruction.py::test_a_sheet_and_its_mirror_image_give_the_same_captures``),
    so the normals are also scored against the mirrored truth ``(-nx, -ny, nz)`` and the
    better of the two counts (``"mirror": true`` when it is the mirror's).
    """
    from thinfilm.core.io import read_dataset
    from thinfilm.evaluation import geometry_error_maps

    ds = read_dataset(dataset, need=("ground_truth",), optional=())
    gt = ds.ground_truth
    maps = geometry_error_maps(gt, estimate)
    mirror = False
    if mirror_equivalent:
        gt_m = dict(gt, normal=gt["normal"] * np.array([-1.0, -1.0, 1.0], dtype=gt["normal"].dtype))
        maps_m = geometry_error_maps(gt_m, estimate)
        if np.nanmean(maps_m["normal_error_deg"]) < np.nanmean(maps["normal_error_deg"]):
            maps, mirror = maps_m, True
    sel = gt["mask"] & np.asarray(estimate.valid, dtype=bool)
    ne = maps["normal_error_deg"][sel]
    te = maps["thickness_error_nm"][sel]
    out = {"coverage": float(sel.sum() / max(1, gt["mask"].sum())),
           "normal_mean": float(np.nanmean(ne)) if ne.size else float("inf"),
           "normal_p95": float(np.nanpercentile(ne, 95)) if ne.size else float("inf"),
           "thickness_mean": float(np.nanmean(te)) if te.size else float("inf"), "mirror": mirror}
    # calibration of the estimate's uncertainty: the share of pixels whose error is within 2 σ
    # (and the pixel counts, for pooling over scenes)
    if getattr(estimate, "normal_sigma_deg", None) is not None:
        for key, err, sig in (("normal", ne, np.asarray(estimate.normal_sigma_deg)[sel]),
                              ("thickness", te, np.asarray(estimate.thickness_sigma_nm)[sel])):
            fin = np.isfinite(err)
            out[f"{key}_within_2sigma"] = int(np.sum(err[fin] <= 2.0 * np.nan_to_num(sig[fin], nan=np.inf)))
            out[f"{key}_sigma_pixels"] = int(fin.sum())
    if kind == "spectral":
        from thinfilm.core.film import Film, as_index

        true = ds.film().effective_index()
        est = Film.single(as_index(estimate.film_ior, "estimate"), None, 1.5).effective_index()
        out["film_ior_error"] = abs(est - true)
    return out


def pool_calibration(calibration: dict, key: str, s: dict) -> str:
    """Adds a score's σ calibration counts (:func:`score`) to ``calibration[key]`` and returns
    the scene's ``2sigma NORMAL/THICKNESS`` text ("" without σ)."""
    if "normal_sigma_pixels" not in s:
        return ""
    cal = calibration.setdefault(key, {"normal": [0, 0], "thickness": [0, 0]})
    fr = []
    for q in ("normal", "thickness"):
        cal[q][0] += s[f"{q}_within_2sigma"]
        cal[q][1] += s[f"{q}_sigma_pixels"]
        fr.append(s[f"{q}_within_2sigma"] / max(1, s[f"{q}_sigma_pixels"]))
    return f" 2sigma {fr[0]:.3f}/{fr[1]:.3f}"


def print_calibration(calibration: dict):
    """The pooled σ calibration of :func:`pool_calibration`, one line per method."""
    for k, cal in calibration.items():
        print(f"calibration {k}: error within 2 sigma for " + ", ".join(
            f"{q} {v[0] / max(1, v[1]):.3f} of {v[1]} pixels" for q, v in cal.items()))


def passes(kind: str, s: dict) -> bool:
    bars = BARS[kind]
    for key, bar in bars.items():
        value = s.get(key)
        if value is None or not np.isfinite(value):
            return False
        if key == "coverage" and value < bar:
            return False
        if key != "coverage" and value > bar:
            return False
    return True


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1, help="sweep seed (which scenes)")
    ap.add_argument("--count", type=int, default=16)
    ap.add_argument("--resolution", type=int, default=96)
    ap.add_argument("--work", default="/tmp/sweep")
    ap.add_argument("--hard", action="store_true", help="also groups of objects and films above the substrate")
    ap.add_argument("--kinds", nargs="+", default=["rgb", "spectral"])
    ap.add_argument("--methods", nargs="+", default=None, help="method names (default: each kind's default)")
    ap.add_argument("--no-generate", action="store_true", help="only reconstruct and score existing datasets")
    ap.add_argument("--only", nargs="+", type=int, default=None, help="scene indices to run")
    ap.add_argument("--json", default=None, help="write the scores here")
    args = ap.parse_args(argv)

    from thinfilm.core.errors import UserError
    from thinfilm.reconstruct import reconstruct

    rng = np.random.default_rng(args.seed)
    specs = [random_spec(rng, args.hard) for _ in range(args.count)]
    work = Path(args.work) / f"{'hard' if args.hard else 'plain'}_s{args.seed}_r{args.resolution}"
    work.mkdir(parents=True, exist_ok=True)
    results = []
    counts = {}
    calibration = {}
    print(f"sweep seed {args.seed}: {args.count} scenes at {args.resolution} px in {work}")
    for i, spec in enumerate(specs):
        if args.only is not None and i not in args.only:
            continue
        ds = work / f"scene{i:02d}"
        if not (ds / "meta.json").is_file():
            if args.no_generate:
                print(f"{i:2d} missing dataset {ds}")
                continue
            import warnings

            from thinfilm.core.variants import use_variant
            from thinfilm.generators.generate import generate_dataset
            from thinfilm.generators.spec import load_spec

            use_variant()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                generate_dataset(load_spec(spec, resolution=args.resolution), ds, progress=False)
            (ds / "sweep_spec.json").write_text(json.dumps(spec, indent=1))
        row = {"index": i, "scene": describe(spec)}
        for kind in args.kinds:
            for method in (args.methods or [None]):
                t0 = time.perf_counter()
                try:
                    import warnings

                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        est, m = reconstruct(kind, ds, method)
                    s = score(ds, est, kind, mirror_equivalent=spec["shape"]["kind"] == "sheet")
                    name = m.name
                except UserError as e:
                    s, name = {"error": str(e)}, method or "default"
                except Exception as e:  # report and go on
                    s, name = {"error": f"{type(e).__name__}: {e}"}, method or "default"
                    traceback.print_exc()
                s["seconds"] = time.perf_counter() - t0
                ok = "error" not in s and passes(kind, s)
                s["pass"] = ok
                key = f"{kind}/{name}"
                row[key] = s
                counts.setdefault(key, [0, 0, 0])
                counts[key][0] += ok
                counts[key][1] += ok and not s.get("mirror", False)
                counts[key][2] += 1
                if "error" not in s:
                    s["calibration_text"] = pool_calibration(calibration, key, s)
        results.append(row)
        parts = []
        for key, s in row.items():
            if not isinstance(s, dict):
                continue
            if "error" in s:
                parts.append(f"{key}: ERROR {s['error'][:90]}")
                continue
            text = (f"{key}: {'ok ' if s['pass'] else 'BAD'} n {s['normal_mean']:.2f}/{s['normal_p95']:.2f} "
                    f"{'(mirror) ' if s.get('mirror') else ''}t {s['thickness_mean']:.1f}")
            if "film_ior_error" in s:
                text += f" n2 {s['film_ior_error']:.3f} cov {s['coverage']:.2f}"
            parts.append(text + s.pop("calibration_text", "") + f" ({s['seconds']:.1f}s)")
        print(f"{i:2d} {row['scene']}\n     " + "\n     ".join(parts), flush=True)
    print("passed: " + ", ".join(f"{k} {v[0]}/{v[2]}" for k, v in counts.items()))
    print("passed without the sheets' mirror images: " + ", ".join(f"{k} {v[1]}/{v[2]}" for k, v in counts.items()))
    print_calibration(calibration)
    if args.json:
        Path(args.json).write_text(json.dumps({"seed": args.seed, "results": results, "counts": counts}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
