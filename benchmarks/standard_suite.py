"""The public scene suite (``scenes/suites/standard.toml``) reconstructed by the default
methods and scored at the bars of :mod:`sweep_random_scenes` (no re-rendering).

Usage::

    .venv/bin/python benchmarks/standard_suite.py [--resolution 96] [--work /tmp/standard]
        [--methods NAME ...] [--only NAME ...] [--no-generate]

Prints one row per scene and kind (normal error mean/p95 in degrees, thickness error in nm,
film-index error, coverage, pass/fail, and the share of pixels whose normal and thickness
errors lie within twice the estimate's σ) and the pass counts, then the σ calibration pooled
over the pixels of all scenes. ``thinfilm benchmark --suite
standard`` runs the same suite with re-rendering and the full report.
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from sweep_random_scenes import passes, pool_calibration, print_calibration, score  # noqa: E402

SUITE = Path(__file__).resolve().parents[1] / "scenes" / "suites" / "standard.toml"


def load_suite(path=SUITE):
    """The suite's scenes: dicts with ``name``, ``spec`` (absolute path), ``resolution``,
    ``seeds``, ``overrides``, ``kinds``."""
    path = Path(path)
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    out = []
    for s in data["scenes"]:
        out.append({"name": s["name"], "spec": str((path.parent / s["spec"]).resolve()),
                    "resolution": s.get("resolution"), "seeds": s.get("seeds"),
                    "overrides": s.get("overrides", []), "kinds": s.get("kinds", ["rgb", "spectral"])})
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=None, help="override the suite's resolution")
    ap.add_argument("--work", default="/tmp/standard")
    ap.add_argument("--methods", nargs="+", default=None)
    ap.add_argument("--only", nargs="+", default=None)
    ap.add_argument("--no-generate", action="store_true")
    ap.add_argument("--refine", action="store_true", help="also refine each estimate (rows METHOD+refine)")
    args = ap.parse_args(argv)

    from thinfilm.core.errors import UserError
    from thinfilm.reconstruct import reconstruct

    work = Path(args.work)
    counts = {}
    calibration = {}
    for scene in load_suite():
        if args.only and scene["name"] not in args.only:
            continue
        res = args.resolution or scene["resolution"]
        for seed in scene["seeds"] or [None]:
            ds = work / f"{scene['name']}_r{res}_s{seed}"
            if not (ds / "meta.json").is_file():
                if args.no_generate:
                    print(f"{scene['name']}: no dataset at {ds}")
                    continue
                from thinfilm.core.variants import use_variant
                from thinfilm.generators.generate import generate_dataset
                from thinfilm.generators.spec import load_spec

                use_variant()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    spec = load_spec(scene["spec"], overrides=scene["overrides"], resolution=res, seed=seed)
                generate_dataset(spec, ds, progress=False)
            for kind in scene["kinds"]:
                for method in args.methods or [None]:
                    t0 = time.perf_counter()
                    try:
                        with warnings.catch_warnings():
                            warnings.simplefilter("ignore")
                            est, m = reconstruct(kind, ds, method)
                    except UserError as e:
                        print(f"{scene['name']:22s} {kind:8s} {method or '-':9s} refused: {e}")
                        continue
                    rows = [(est, m.name, time.perf_counter() - t0)]
                    if args.refine:
                        from thinfilm.refine import refine

                        t1 = time.perf_counter()
                        with warnings.catch_warnings():
                            warnings.simplefilter("ignore")
                            rows.append((refine(ds, est), f"{m.name}+refine", time.perf_counter() - t1))
                    for est, name, seconds in rows:
                        row(scene, kind, ds, est, name, seconds, counts, calibration)
    print("passed: " + ", ".join(f"{k} {v[0]}/{v[1]}" for k, v in counts.items()))
    print_calibration(calibration)
    return 0


def row(scene, kind, ds, est, name, seconds, counts, calibration):
    """Scores one estimate, prints its row and adds it to the counts."""
    s = score(ds, est, kind)
    ok = passes(kind, s)
    key = f"{kind}/{name}"
    counts.setdefault(key, [0, 0])
    counts[key][0] += ok
    counts[key][1] += 1
    extra = f" n2 {s['film_ior_error']:.4f}" if "film_ior_error" in s else ""
    extra += pool_calibration(calibration, key, s)
    print(f"{scene['name']:22s} {kind:8s} {name:16s} {'ok ' if ok else 'BAD'} normal "
          f"{s['normal_mean']:5.2f}/{s['normal_p95']:5.2f} thickness {s['thickness_mean']:6.2f}"
          f"{extra} coverage {s['coverage']:.3f} ({seconds:.1f} s)", flush=True)


if __name__ == "__main__":
    sys.exit(main())
