"""Scenes and surface interactions shared by the plugin tests (``test_plugin``, ``test_sheet``,
``test_stack_plugin``): a tilted plane under a uniform dome seen by an orthographic camera, its
Stokes images, and random surface interactions for calling a BSDF directly."""

import numpy as np

__all__ = ["normal_from_angles", "orthographic_sensor", "plane_scene", "stokes_images", "random_interactions"]


def normal_from_angles(theta_deg, phi_deg):
    """The unit vector of zenith ``theta_deg`` and azimuth ``phi_deg`` (camera frame, z to the camera)."""
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def orthographic_sensor(mi, res, spp=1, stratified=True, seed=0):
    """An orthographic camera on +z looking at the origin, ``res`` x ``res`` RGB pixels, box filter;
    a non-jittered stratified sampler (pixel-centre rays), or an independent one."""
    sampler = ({"type": "stratified", "sample_count": spp, "jitter": False, "seed": seed} if stratified
               else {"type": "independent", "sample_count": spp, "seed": seed})
    return {
        "type": "orthographic",
        "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
        "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"},
                 "pixel_format": "rgb"},
        "sampler": sampler,
    }


def plane_scene(mi, bsdf, theta_deg, phi_deg, res=4):
    """A plane whose normal has zenith θ and azimuth φ in the camera frame, under a uniform dome."""
    n = normal_from_angles(theta_deg, phi_deg)
    up = [0, 1, 0] if abs(n[1]) < 0.9 else [1, 0, 0]
    to_world = mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=list(n), up=up)
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "stokes", "nested": {"type": "path", "max_depth": 2, "hide_emitters": True}},
        "sensor": orthographic_sensor(mi, res),
        "emitter": {"type": "constant", "radiance": {"type": "uniform", "value": 1.0}},
        "plane": {"type": "rectangle", "to_world": to_world @ mi.ScalarTransform4f().scale(20.0), "bsdf": bsdf},
    })


def stokes_images(mi, scene):
    """S0, S1, S2, S3 images (first colour channel) of a stokes-integrator render."""
    img = np.array(mi.render(scene), dtype=np.float64)
    # Channels: [Y or R,G,B] then S0.RGB, S1.RGB, S2.RGB, S3.RGB.
    base = img.shape[-1] - 12
    return [img[..., base + 3 * i] for i in range(4)]


def random_interactions(mi, n, seed):
    """Surface interactions on a surface of normal +z with random incident directions (and
    random wavelengths): one of ``n`` lanes in vectorized variants, ``n`` single ones in scalar
    variants, in a list."""
    import drjit as dr

    rng = np.random.default_rng(seed)
    cos_t = rng.uniform(0.02, 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    sin_t = np.sqrt(1 - cos_t**2)
    si = dr.zeros(mi.SurfaceInteraction3f, n) if mi.variant().startswith("llvm") else dr.zeros(mi.SurfaceInteraction3f)
    if mi.variant().startswith("llvm"):
        si.wi = mi.Vector3f(sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t)
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        si.n = mi.Vector3f(0, 0, 1)
        si.wavelengths = mi.UnpolarizedSpectrum(*[mi.Float(rng.uniform(380, 780, n)) for _ in range(4)]) \
            if mi.is_spectral else si.wavelengths
        return [si]
    out = []
    for i in range(n):
        s = dr.zeros(mi.SurfaceInteraction3f)
        s.wi = mi.Vector3f(sin_t[i] * np.cos(phi[i]), sin_t[i] * np.sin(phi[i]), cos_t[i])
        s.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        s.n = mi.Vector3f(0, 0, 1)
        s.wavelengths = mi.UnpolarizedSpectrum(*rng.uniform(380, 780, 4))
        out.append(s)
    return out
