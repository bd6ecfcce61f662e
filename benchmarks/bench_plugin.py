"""Benchmark: render time of the thinfilm BSDF against Mitsuba's native ``conductor``.

Same scene (spheres under a uniform dome, stokes + path integrator, orthographic camera),
spectral polarized variant, 512x512 at 16 spp by default; both BSDFs are warmed up (kernels
compiled) before timing; their renders alternate, and the median of each one's is reported
(``_bsdf_bench.py``).

    python benchmarks/bench_plugin.py [--variant llvm_ad_spectral_polarized] [--res 512] [--spp 16] [--repeats 15]
"""

import argparse
import statistics

from _bsdf_bench import compare, scene_dict


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", default="llvm_ad_spectral_polarized")
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=15, help="alternated renders of each BSDF")
    args = ap.parse_args()

    import drjit as dr
    import mitsuba as mi

    mi.set_variant(args.variant)
    import thinfilm.bsdf

    thinfilm.bsdf.register()
    conductor = mi.load_dict(scene_dict(mi, {"type": "conductor", "eta": 1.6, "k": 0.0}, args.res, args.spp))
    film = mi.load_dict(scene_dict(mi, {"type": "thinfilm", "thickness": 400.0, "film_ior": 1.37,
                                        "substrate_ior": 1.6}, args.res, args.spp))
    times, _ = compare(mi, dr, {"conductor": conductor, "thinfilm": film}, args.repeats)
    t_cond, t_film = (statistics.median(t[0] for t in times[k]) for k in ("conductor", "thinfilm"))
    print(f"variant {args.variant}, {args.res}x{args.res}, {args.spp} spp, median of {args.repeats} alternated "
          f"renders each")
    print(f"  native conductor : {t_cond * 1e3:8.1f} ms")
    print(f"  thinfilm         : {t_film * 1e3:8.1f} ms")
    print(f"  ratio thinfilm / conductor = {t_film / t_cond:.3f}   (target <= 1.1)")


if __name__ == "__main__":
    main()
