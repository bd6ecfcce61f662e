"""Band-integrated Stokes cubes rendered through the ``thinfilm`` plugin.

Rendering runs in Mitsuba's ``llvm_ad_mono_polarized`` variant (the caller sets it): the
``stokes`` integrator with one non-jittered sample per pixel, so every pixel is the exact
pixel-centre ray and images are deterministic. The variant carries no wavelength; the
plugin's ``wavelength`` parameter is changed through ``mi.traverse`` between renders, which
reuses the compiled kernel (about 10-20 ms per 256 x 256 render on 2 cores).

Rough films
-----------
A rough film (``alpha > 0``) scatters each pixel-centre ray into a lobe, which one sample per
pixel cannot integrate. With ``spp > 1`` every pixel still gets only its pixel-centre camera
ray, ``spp`` times, and only the BSDF (and light) samples vary: the pixel is the lobe
integral at the macro surface point the ground truth describes, not an average over the
pixel's area. The loop is this module's (:func:`_render_samples`), not ``mi.render``, for two
reasons: Mitsuba's samplers put ``spp`` > 1 samples at different points of the pixel, and its
film adds a pixel's samples in whatever order its threads finish, which is not the same
from run to run. Here the nested integrator is called directly (the ``stokes`` integrator's
rotation into the camera's Stokes frame is applied here, as that integrator does), samples
come from Mitsuba's ``ldsampler`` (a scrambled (0, 2) sequence per pixel, so the lobe
integral converges about as 1/spp rather than 1/sqrt(spp)) and each pixel's samples are
summed in float64 by NumPy in a fixed order: the same seed gives the same bytes. Each
sub-wavelength render gets its own seed (drawn from ``seed``), so the sampling noise of a
band averages over the renders it is made of and is independent from band to band, as a
camera's is.

Band integration
----------------
Each band is the passband-weighted mean of renders at several sub-wavelengths, by the one
quadrature of :func:`thinfilm.core.bands.passband_quadrature` (which the observation model,
:mod:`thinfilm.core.model`, uses too).
"""

from __future__ import annotations

import math

import numpy as np

from thinfilm.core.bands import passband_quadrature

__all__ = [
    "require_render_variant",
    "render_stokes_cube",
    "render_seeds",
    "sample_blocks",
    "ROUGH_SAMPLER",
    "MAX_LANES",
]

#: sampler of the many-sample path: blocks of a power of 4 samples (:func:`sample_blocks`)
ROUGH_SAMPLER = "ldsampler"
#: samples traced per kernel launch (rows of the image are rendered in groups of at most this)
MAX_LANES = 1 << 21


def require_render_variant():
    """The ``mitsuba`` module, once the caller's variant is checked to be a vectorized
    ``*_mono_polarized`` one (e.g. ``llvm_ad_mono_polarized``) and the ``thinfilm`` and
    ``imagespace`` plugins are registered in it.

    Raises
    ------
    RuntimeError
        When no such variant is set (library code never sets one).
    """
    import mitsuba as mi

    from .scene import register_plugins

    variant = mi.variant() or ""
    if not variant.endswith("mono_polarized") or variant.startswith("scalar"):
        raise RuntimeError(f"rendering Stokes cubes needs a vectorized *_mono_polarized Mitsuba "
                           f"variant (e.g. llvm_ad_mono_polarized) set by the caller, the current "
                           f"one is {variant or 'not set'}")
    register_plugins()
    return mi


def _stokes_channels(scene):
    """Indices of S0, S1, S2 in the film's output (first colour channel of each)."""
    film = scene.sensors()[0].film()
    st = film.bitmap().struct_() if hasattr(film, "bitmap") else None
    names = [st[i].name for i in range(len(st))] if st is not None else []
    try:
        return [names.index(f"S{i}.R") if f"S{i}.R" in names else names.index(f"S{i}.Y")
                for i in range(3)]
    except ValueError:
        raise RuntimeError(f"film channels {names} hold no Stokes components; use the 'stokes' "
                           f"integrator in a polarized variant") from None


def render_stokes_cube(scene, wavelengths_nm, band_fwhm_nm: float, passband: str = "gaussian",
                       progress: bool = False, spp: int = 1, seed: int = 0, integrator=None) -> dict:
    """Render the band-integrated Stokes cube of a scene.

    Parameters
    ----------
    scene : dict or mitsuba.Scene
        A scene with the ``stokes`` integrator, an ``hdrfilm`` and ``thinfilm`` BSDFs, as made
        by :func:`thinfilm.generators.scene.build_scene` or ``normal_map_scene``. The
        variant must be ``*_mono_polarized`` (set by the caller).
    wavelengths_nm : array (B,)
        Band centres.
    band_fwhm_nm : float
        Passband width (see :func:`thinfilm.core.bands.passband_quadrature`).
    passband : {"gaussian", "box"}
    progress : bool
        tqdm progress bar on stderr (shown only on a terminal).
    spp : int
        Samples per pixel. 1 (smooth films): ``mi.render`` with the scene's own sampler and
        integrator, one pixel-centre ray per pixel. More (rough films): the pixel-centre ray
        ``spp`` times with varying BSDF samples (see the module docstring), rounded up as
        :func:`sample_blocks` says (powers of 4 are rendered as they are).
    seed : int
        Seed of the many-sample path (>= 0): sub-wavelength render ``k`` uses the ``k``-th
        seed of :func:`render_seeds`. Not used with ``spp = 1``.
    integrator : dict, optional
        Nested sampling integrator of the many-sample path (not the ``stokes`` wrapper);
        default Mitsuba's ``path`` with ``max_depth`` 6 and hidden emitters, which suits any
        scene; :data:`thinfilm.generators.scene.BSDF_SAMPLING_INTEGRATOR` gives the same for
        convex objects in about half the time (:func:`thinfilm.generators.scene.rough_integrator`
        picks one for a scene spec).

    Returns
    -------
    dict
        ``S0``, ``S1``, ``S2``: (H, W, B) float64 in reflectance units (dome radiance 1),
        Stokes frame of ``docs/design.md``, *Conventions* (S1 = I(0°) - I(90°), 0° = image +x);
        ``mask``: (H, W) bool, pixels whose centre ray hits a surface facing the camera.
    """
    from .ground_truth import cast_ground_truth

    mi = require_render_variant()
    if isinstance(scene, dict):
        scene = mi.load_dict(scene)
    params = mi.traverse(scene)
    keys = [k for k in params.keys() if k == "wavelength" or k.endswith(".wavelength")]
    if not keys:
        raise ValueError("the scene has no 'thinfilm' BSDF with a 'wavelength' parameter")
    sub_nm, weights = passband_quadrature(wavelengths_nm, float(band_fwhm_nm), passband)
    width, height = (int(v) for v in scene.sensors()[0].film().size())
    if int(spp) != spp or spp < 1:
        raise ValueError(f"spp must be a whole number >= 1, got {spp!r}")
    if spp > 1:
        cube = _render_rough_cube(mi, scene, params, keys, sub_nm, weights, int(spp), int(seed),
                                  integrator, progress)
        out = {name: np.ascontiguousarray(np.moveaxis(cube[i], 0, -1))
               for i, name in enumerate(("S0", "S1", "S2"))}
        out["mask"] = cast_ground_truth(scene)["mask"]
        return out
    # Render once so the film's channel layout is known.
    _set_wavelength(params, keys, float(sub_nm[0]))
    first = np.asarray(mi.render(scene, spp=1, seed=0))
    channels = _stokes_channels(scene)

    cube = np.zeros((3, weights.shape[0], height, width), dtype=np.float64)
    from tqdm import tqdm

    bar = tqdm(total=len(sub_nm), desc="rendering", unit="λ", leave=False,
               disable=None if progress else True)
    for k, lam in enumerate(sub_nm):
        if k == 0:
            img = first
        else:
            _set_wavelength(params, keys, float(lam))
            img = np.asarray(mi.render(scene, spp=1, seed=0))
        s = np.moveaxis(img[..., channels], -1, 0).astype(np.float64)
        for b in np.nonzero(weights[:, k])[0]:
            cube[:, b] += weights[b, k] * s
        bar.update(1)
    bar.close()
    mask = cast_ground_truth(scene)["mask"]
    out = {name: np.ascontiguousarray(np.moveaxis(cube[i], 0, -1)) for i, name in enumerate(("S0", "S1", "S2"))}
    out["mask"] = mask
    return out


def _set_wavelength(params, keys, lam: float) -> None:
    for key in keys:
        params[key] = lam
    params.update()


def render_seeds(seed: int, count: int) -> np.ndarray:
    """``count`` 32-bit sampler seeds drawn from ``seed`` (one per sub-wavelength render of the
    many-sample path): the same ``seed`` gives the same seeds, and the first ``m`` of them do
    not depend on ``count``.

    Examples
    --------
    >>> a = render_seeds(0, 3)
    >>> a.dtype, a.shape, bool(a[0] != a[1])
    (dtype('uint32'), (3,), True)
    >>> bool((render_seeds(0, 5)[:3] == a).all())
    True
    """
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a whole number >= 0, got {seed!r}")
    # Tagged: other streams than the camera noise's, which come from the same seed.
    return np.random.SeedSequence([int(seed), 0x726F756768]).generate_state(int(count), dtype=np.uint32)


def sample_blocks(spp: int) -> tuple:
    """``(block, passes)``: the many-sample path renders ``spp`` samples per pixel as
    ``passes`` independently scrambled blocks of ``block`` samples, ``block`` the largest
    power of 4 <= ``spp`` (what Mitsuba's ``ldsampler`` stratifies; at least 4);
    ``block * passes`` >= ``spp`` is what is rendered.

    Examples
    --------
    >>> sample_blocks(64), sample_blocks(100), sample_blocks(256), sample_blocks(2)
    ((64, 1), (64, 2), (256, 1), (4, 1))
    """
    spp = int(spp)
    if spp < 1:
        raise ValueError(f"spp must be >= 1, got {spp}")
    block = max(4, 4 ** int(math.floor(math.log(spp, 4) + 1e-9)))
    return block, -(-spp // block)


def _render_rough_cube(mi, scene, params, keys, sub_nm, weights, spp, seed, integrator, progress):
    """The band-integrated cube (3, B, H, W) of the many-sample path."""
    from tqdm import tqdm

    nested = mi.load_dict(dict(integrator) if integrator is not None else
                          {"type": "path", "max_depth": 6, "hide_emitters": True})
    block, passes = sample_blocks(spp)
    sampler = mi.load_dict({"type": ROUGH_SAMPLER, "sample_count": block})
    sampler.set_samples_per_wavefront(block)
    seeds = render_seeds(seed, len(sub_nm) * passes).reshape(len(sub_nm), passes)
    sensor = scene.sensors()[0]
    width, height = (int(v) for v in sensor.film().size())
    cube = np.zeros((3, weights.shape[0], height, width), dtype=np.float64)
    bar = tqdm(total=len(sub_nm), desc=f"rendering ({block * passes} spp)", unit="λ", leave=False,
               disable=None if progress else True)
    for k, lam in enumerate(sub_nm):
        _set_wavelength(params, keys, float(lam))
        s = sum(_render_samples(mi, scene, nested, sampler, block, int(seeds[k, j]))
                for j in range(passes)) / passes
        for b in np.nonzero(weights[:, k])[0]:
            cube[:, b] += weights[b, k] * s
        bar.update(1)
    bar.close()
    return cube


def _render_samples(mi, scene, nested, sampler, spp: int, seed: int) -> np.ndarray:
    """S0, S1, S2 (3, H, W) float64: the mean of ``spp`` samples of the pixel-centre ray of
    every pixel, through the nested integrator, in the camera's Stokes frame.

    Pixel ``p``'s samples are lanes ``p * spp … p * spp + spp - 1`` of the sampler's
    wavefront. Rows are rendered in groups of at most :data:`MAX_LANES` samples; the seed of
    a group is offset by its first lane, so Mitsuba's per-pixel sequence seeds (a hash of
    the seed plus the pixel's first lane) and thus the images do not depend on the grouping.
    """
    import drjit as dr

    sensor = scene.sensors()[0]
    width, height = (int(v) for v in sensor.film().size())
    vertical = sensor.world_transform() @ mi.Vector3f(0.0, 1.0, 0.0)
    rows_per_group = max(1, MAX_LANES // (width * spp))
    out = np.empty((3, height, width), dtype=np.float64)
    for row0 in range(0, height, rows_per_group):
        rows = min(rows_per_group, height - row0)
        lanes = rows * width * spp
        sampler.seed((seed + row0 * width * spp) % (1 << 32), lanes)
        pixel = dr.arange(mi.UInt32, lanes) // spp
        row = pixel // width
        col = pixel - row * width
        sampler.next_2d()  # the pixel-position dimension of mi.render, unused: the centre is taken
        pos = mi.Point2f((mi.Float(col) + 0.5) * (1.0 / width),
                         (mi.Float(row + row0) + 0.5) * (1.0 / height))
        ray, _ = sensor.sample_ray_differential(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
        ray.scale_differential(float(1.0 / np.sqrt(spp)))
        spec, _, _ = nested.sample(scene, sampler, ray, None, True)
        # As Mitsuba's stokes integrator: from the ray's implicit Stokes basis into the one
        # whose reference direction is the camera's x axis (ray.d x camera up).
        basis = mi.mueller.stokes_basis(-ray.d)
        target = dr.cross(ray.d, vertical)
        spec = mi.mueller.rotate_stokes_basis(-ray.d, basis, target) @ spec
        stokes = [spec[i, 0][0] for i in range(3)]
        dr.eval(*stokes)
        for i in range(3):
            samples = np.asarray(stokes[i], dtype=np.float64).reshape(rows * width, spp)
            out[i, row0:row0 + rows] = samples.sum(axis=1).reshape(rows, width) / spp
    return out
