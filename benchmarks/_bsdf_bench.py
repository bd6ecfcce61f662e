"""The scene and timing shared by the BSDF benchmarks (``bench_plugin.py``, ``bench_rough.py``,
``bench_rgb_variant.py``): two spheres under a uniform dome seen by an orthographic camera,
rendered alternately so that drifts in machine load hit every BSDF alike."""

import time


def scene_dict(mi, bsdf, res, spp, stokes=True):
    """The benchmark scene with ``bsdf`` on both spheres; ``stokes``: the ``stokes`` integrator
    around ``path`` (polarized variants), else ``path`` alone."""
    path = {"type": "path", "max_depth": 4, "hide_emitters": True}
    return {
        "type": "scene",
        "integrator": {"type": "stokes", "nested": path} if stokes else path,
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
    """Wall-clock and CPU (all threads of this process) seconds of one render."""
    t0, c0 = time.perf_counter(), time.process_time()
    img = mi.render(scene, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    return time.perf_counter() - t0, time.process_time() - c0


def compare(mi, dr, scenes, repeats):
    """(wall, CPU) times of each scene's renders by name: every scene rendered once first
    (tracing and kernel compilation, returned under ``"first"``), then ``repeats`` rounds in
    alternation, the order reversed every other round."""
    first = {name: render_time(mi, dr, scene, 0) for name, scene in scenes.items()}
    times = {name: [] for name in scenes}
    for i in range(repeats):
        order = list(scenes) if i % 2 == 0 else list(scenes)[::-1]
        for name in order:
            times[name].append(render_time(mi, dr, scenes[name], i + 1))
    return times, first
