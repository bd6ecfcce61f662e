"""Benchmark: render time of the thinfilm BSDF against Mitsuba's native ``conductor``.

Same scene (spheres under a uniform dome, stokes + path integrator, orthographic camera),
spectral polarized variant, 512x512 at 16 spp by default; both BSDFs are warmed up (kernels
compiled) before timing; rounds of renders of each alternate, and the median of each one's
renders is reported.

    python benchmarks/bench_plugin.py [--variant llvm_ad_spectral_polarized] [--res 512] [--spp 16] [--repeats 5] [--rounds 3]
"""

import argparse
import statistics
import time


def scene_dict(mi, bsdf, res, spp):
    return {
        "type": "scene",
        "integrator": {"type": "stokes", "nested": {"type": "path", "max_depth": 4, "hide_emitters": True}},
        "sensor": {
            "type": "orthographic",
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0])
            @ mi.ScalarTransform4f().scale([1.6, 1.6, 1]),
            "film": {"type": "hdrfilm", "width": res, "height": res},
            "sampler": {"type": "independent", "sample_count": spp},
        },
        "emitter": {"type": "constant"},
        "a": {"type": "sphere", "radius": 0.9, "center": [-0.5, 0, 0], "bsdf": bsdf},
        "b": {"type": "sphere", "radius": 0.6, "center": [0.8, 0.6, 0.3], "bsdf": bsdf},
    }


def time_render(mi, dr, scene, repeats):
    mi.render(scene, seed=0)  # warm-up: trace and compile
    dr.sync_thread()
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        img = mi.render(scene, seed=i + 1)
        dr.eval(img)
        dr.sync_thread()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", default="llvm_ad_spectral_polarized")
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--rounds", type=int, default=3, help="alternated rounds of --repeats renders each")
    args = ap.parse_args()

    import drjit as dr
    import mitsuba as mi

    mi.set_variant(args.variant)
    import thinfilm.bsdf

    thinfilm.bsdf.register()
    conductor = mi.load_dict(scene_dict(mi, {"type": "conductor", "eta": 1.6, "k": 0.0}, args.res, args.spp))
    film = mi.load_dict(scene_dict(mi, {"type": "thinfilm", "thickness": 400.0, "film_ior": 1.37,
                                        "substrate_ior": 1.6}, args.res, args.spp))
    # Alternate (conductor, thinfilm) rounds to share any drift in machine load between the
    # two; each side's time is the median of all its renders
    runs_cond, runs_film = [], []
    for _ in range(args.rounds):
        runs_cond += time_render(mi, dr, conductor, args.repeats)[1]
        runs_film += time_render(mi, dr, film, args.repeats)[1]
    t_cond, t_film = statistics.median(runs_cond), statistics.median(runs_film)
    print(f"variant {args.variant}, {args.res}x{args.res}, {args.spp} spp, median of {args.rounds} x {args.repeats} "
          f"alternated renders each")
    print(f"  native conductor : {t_cond * 1e3:8.1f} ms")
    print(f"  thinfilm         : {t_film * 1e3:8.1f} ms")
    print(f"  ratio thinfilm / conductor = {t_film / t_cond:.3f}   (target <= 1.1)")


if __name__ == "__main__":
    main()
