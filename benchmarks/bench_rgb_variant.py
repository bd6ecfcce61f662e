"""Benchmark: the thinfilm BSDF in an RGB variant against Mitsuba's native ``conductor``.

Same scene for both (two spheres under a uniform sky, path integrator, orthographic camera,
512x512 at 16 spp by default) in ``llvm_ad_rgb``; kernels are compiled before timing, the two
BSDFs are rendered alternately (so drifts in machine load hit both), and the medians are
compared. Prints the absolute times and the ratio thinfilm / conductor.

    python benchmarks/bench_rgb_variant.py [--variant llvm_ad_rgb] [--res 512] [--spp 16] [--repeats 7]

With ``--accuracy`` it instead measures colour accuracy: a thin-film sphere filling an
orthographic view under a white sky (constant emitter), rendered by Mitsuba in
``llvm_ad_spectral`` (two seeds at ``--reference-spp``, converted to sRGB by Mitsuba's film) and
in ``llvm_ad_rgb``; prints ΔE*ab (colour-science, CIE 1976) over the fully covered pixels, of
RGB against the mean of the two spectral renders and, as the reference's own noise level, of
the two spectral renders against each other.

    python benchmarks/bench_rgb_variant.py --accuracy [--res 64] [--reference-spp 16384]
"""

import argparse
import statistics

from _bsdf_bench import compare, scene_dict


ACCURACY_CASES = {
    "defaults: n=1.37 400 nm on 1.6": {"thickness": 400.0},
    "PET 650 nm on 1.5": {"thickness": 650.0, "film_ior": "PET", "substrate_ior": 1.5},
    "MgF2 300 nm on metal": {"thickness": 300.0, "film_ior": "MgF2", "substrate_ior": 0.2, "substrate_k": 3.0},
    "n=2.0 250 nm on 1.5": {"thickness": 250.0, "film_ior": 2.0, "substrate_ior": 1.5},
    "n=1.45 1000 nm on 1.6": {"thickness": 1000.0, "film_ior": 1.45, "substrate_ior": 1.6},
}


def sphere_render(mi, bsdf, res, spp, seed):
    """Linear sRGB + alpha image of a unit sphere filling an orthographic view, white sky."""
    import numpy as np

    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 2, "hide_emitters": True},
        "sensor": {"type": "orthographic",
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "pixel_format": "rgba",
                            "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "emitter": {"type": "constant"},
        "sphere": {"type": "sphere", "radius": 1.0, "bsdf": bsdf},
    })
    return np.array(mi.render(scene, seed=seed), dtype=np.float64)


def accuracy(args):
    import colour
    import mitsuba as mi
    import numpy as np

    import thinfilm.bsdf

    def lab(rgb):
        xyz = colour.RGB_to_XYZ(rgb, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False)
        return colour.XYZ_to_Lab(xyz, colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])

    def stats(a, b, mask):
        d = colour.delta_E(lab(a[mask][:, :3]), lab(b[mask][:, :3]), method="CIE 1976")
        return f"mean {d.mean():.3f}  p95 {np.percentile(d, 95):.3f}  max {d.max():.3f}"

    print(f"sphere {args.res}x{args.res}, white sky; spectral reference 2 x {args.reference_spp} spp, "
          f"RGB {args.rgb_spp} spp; dE*ab over fully covered pixels")
    for name, params in ACCURACY_CASES.items():
        bsdf = dict(type="thinfilm", **params)
        images = {}
        for variant, spp, seeds in (("llvm_ad_spectral", args.reference_spp, (0, 1)), ("llvm_ad_rgb", args.rgb_spp, (2,))):
            mi.set_variant(variant)
            thinfilm.bsdf.register()
            images[variant] = [sphere_render(mi, bsdf, args.res, spp, seed) for seed in seeds]
        s0, s1 = images["llvm_ad_spectral"]
        rgb = images["llvm_ad_rgb"][0]
        mask = (s0[..., 3] > 0.999) & (s1[..., 3] > 0.999) & (rgb[..., 3] > 0.999)
        print(f"  {name:31s} RGB vs spectral: {stats(rgb, 0.5 * (s0 + s1), mask)}   "
              f"(spectral vs spectral: {stats(s0, s1, mask)})")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--accuracy", action="store_true", help="measure dE*ab against Mitsuba's spectral render")
    ap.add_argument("--reference-spp", type=int, default=16384)
    ap.add_argument("--rgb-spp", type=int, default=1024)
    args = ap.parse_args()
    if args.accuracy:
        if args.res == 512:
            args.res = 64
        return accuracy(args)

    import drjit as dr
    import mitsuba as mi

    mi.set_variant(args.variant)
    import thinfilm.bsdf

    thinfilm.bsdf.register()
    scenes = {
        "conductor": mi.load_dict(scene_dict(mi, {"type": "conductor", "eta": 1.6, "k": 0.0}, args.res, args.spp,
                                              stokes=False)),
        "thinfilm": mi.load_dict(scene_dict(mi, {"type": "thinfilm", "thickness": 400.0, "film_ior": 1.37,
                                                 "substrate_ior": 1.6}, args.res, args.spp, stokes=False)),
    }
    times, first = compare(mi, dr, scenes, args.repeats)
    times = {name: [t[0] for t in ts] for name, ts in times.items()}
    compile_s = {name: t[0] for name, t in first.items()}
    med = {name: statistics.median(t) for name, t in times.items()}
    print(f"variant {args.variant}, {args.res}x{args.res}, {args.spp} spp, median of {args.repeats} alternate runs")
    for name in scenes:
        runs = " ".join(f"{t * 1e3:.0f}" for t in times[name])
        print(f"  {name:10s}: {med[name] * 1e3:8.1f} ms   (first render with compilation "
              f"{compile_s[name] * 1e3:.0f} ms; runs: {runs})")
    print(f"  ratio thinfilm / conductor = {med['thinfilm'] / med['conductor']:.3f}   (target <= 1.5, goal 1.2)")


if __name__ == "__main__":
    main()
