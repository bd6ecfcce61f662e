"""Benchmark: the thinfilm BSDF in an RGB variant against Mitsuba's native ``conductor``.

Same scene for both (two spheres under a uniform sky, path integrator, orthographic camera,
512x512 at 16 spp by default) in ``llvm_ad_rgb``; kernels are compiled before timing, the two
BSDFs are rendered alternately (so drifts in machine load hit both), and the medians are
compared. Prints the absolute times and the ratio thinfilm / conductor.

    python benchmarks/bench_rgb_variant.py [--variant llvm_ad_rgb] [--res 512] [--spp 16] [--repeats 7]
"""

import argparse
import statistics
import time


def scene_dict(mi, bsdf, res, spp):
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 4, "hide_emitters": True},
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


def render_time(mi, dr, scene, seed):
    t0 = time.perf_counter()
    img = mi.render(scene, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()

    import drjit as dr
    import mitsuba as mi

    mi.set_variant(args.variant)
    import thinfilm.bsdf

    thinfilm.bsdf.register()
    scenes = {
        "conductor": mi.load_dict(scene_dict(mi, {"type": "conductor", "eta": 1.6, "k": 0.0}, args.res, args.spp)),
        "thinfilm": mi.load_dict(scene_dict(mi, {"type": "thinfilm", "thickness": 400.0, "film_ior": 1.37,
                                                 "substrate_ior": 1.6}, args.res, args.spp)),
    }
    compile_s = {name: render_time(mi, dr, scene, 0) for name, scene in scenes.items()}  # trace + compile
    times = {name: [] for name in scenes}
    for i in range(args.repeats):
        order = list(scenes) if i % 2 == 0 else list(scenes)[::-1]
        for name in order:
            times[name].append(render_time(mi, dr, scenes[name], i + 1))
    med = {name: statistics.median(t) for name, t in times.items()}
    print(f"variant {args.variant}, {args.res}x{args.res}, {args.spp} spp, median of {args.repeats} alternate runs")
    for name in scenes:
        runs = " ".join(f"{t * 1e3:.0f}" for t in times[name])
        print(f"  {name:10s}: {med[name] * 1e3:8.1f} ms   (first render with compilation "
              f"{compile_s[name] * 1e3:.0f} ms; runs: {runs})")
    print(f"  ratio thinfilm / conductor = {med['thinfilm'] / med['conductor']:.3f}   (target <= 1.5, goal 1.2)")


if __name__ == "__main__":
    main()
