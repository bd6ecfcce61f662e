"""Benchmark: render time of the rough thinfilm BSDF against Mitsuba's native ``roughconductor``.

Same scene as ``bench_plugin.py`` (spheres under a uniform dome, stokes + path integrator,
orthographic camera), spectral polarized variant, 512x512 at 16 spp by default, the same
roughness (GGX, alpha 0.2) for both. Both scenes are warmed up (kernels compiled) first, then
rendered alternately; the medians are reported. ``--smooth`` also times the smooth film
(alpha = 0) against ``conductor``, the ratio ``bench_plugin.py`` prints.

    python benchmarks/bench_rough.py [--variant llvm_ad_spectral_polarized] [--res 512] [--spp 16]
                                     [--repeats 5] [--alpha 0.2] [--distribution ggx] [--smooth]
"""

import argparse
import statistics

from _bsdf_bench import compare, scene_dict


def ratios(times, name, baseline, which):
    """Ratio of the medians, and the median of the ratios of renders done one after the other
    (less sensitive to load that drifts during the run); ``which`` 0 for wall, 1 for CPU time."""
    a = [t[which] for t in times[name]]
    b = [t[which] for t in times[baseline]]
    paired = statistics.median(x / y for x, y in zip(a, b))
    return statistics.median(a) / statistics.median(b), paired


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", default="llvm_ad_spectral_polarized")
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--alpha", type=float, default=0.2)
    ap.add_argument("--distribution", default="ggx", choices=["ggx", "beckmann"])
    ap.add_argument("--smooth", action="store_true", help="also time the smooth film against conductor")
    args = ap.parse_args()

    import drjit as dr
    import mitsuba as mi

    mi.set_variant(args.variant)
    import thinfilm.bsdf

    thinfilm.bsdf.register()
    rough = {"alpha": args.alpha, "distribution": args.distribution}
    film = {"type": "thinfilm", "thickness": 400.0, "film_ior": 1.37, "substrate_ior": 1.6}
    scenes = {
        "roughconductor": {"type": "roughconductor", "eta": 1.6, "k": 0.0, **rough},
        "rough thinfilm": {**film, **rough},
    }
    if args.smooth:
        scenes["conductor"] = {"type": "conductor", "eta": 1.6, "k": 0.0}
        scenes["smooth thinfilm"] = film
    scenes = {name: mi.load_dict(scene_dict(mi, bsdf, args.res, args.spp)) for name, bsdf in scenes.items()}
    times, _ = compare(mi, dr, scenes, args.repeats)

    print(f"variant {args.variant}, {args.res}x{args.res}, {args.spp} spp, median of {args.repeats} "
          f"(alternated), {args.distribution} alpha {args.alpha}")
    for name, t in times.items():
        wall, cpu = [x[0] for x in t], [x[1] for x in t]
        print(f"  {name:16s}: wall {statistics.median(wall) * 1e3:8.1f} ms (min {min(wall) * 1e3:7.1f}),"
              f" CPU {statistics.median(cpu) * 1e3:8.1f} ms (min {min(cpu) * 1e3:7.1f})")
    pairs = [("rough thinfilm", "roughconductor", "   (bar <= 1.3, goal <= 1.1)")]
    if args.smooth:
        pairs.append(("smooth thinfilm", "conductor", ""))
    for name, baseline, note in pairs:
        (w, wp), (c, cp) = ratios(times, name, baseline, 0), ratios(times, name, baseline, 1)
        print(f"  {name} / {baseline}: wall {w:.3f} (paired {wp:.3f}), CPU {c:.3f} (paired {cp:.3f}){note}")


if __name__ == "__main__":
    main()
