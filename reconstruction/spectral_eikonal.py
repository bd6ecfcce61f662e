"""The default spectral method: the paper's physics, solved at the object level.

1. peaks as in the paper give a first angle where they exist;
2. ``n2`` once for the object: the (n2, m) search pooled over well-conditioned pixels
   (25°–65°), then a joint Gauss-Newton over the shared ``n2`` and every pixel's (θ, d);
3. every pixel's (θ, d) by Levenberg-Marquardt on the whole spectrum through the optics
   core (pixels without a peak are started from their nearest pixel with one, and from a
   coarse grid where that fit stays poor), with the variance of θ; for the thickness,
   pixels whose fit stays far above the noise (a wrong peak, a wrong order) and the
   pixels without a peak are refitted from the nearest well-fitted pixel;
4. the surface as a whole: ``|∇z| = tan θ`` by fast marching from the occluding boundary,
   then a least-squares refinement weighted by each pixel's angle precision (the
   near-normal region, where the peak reflectance is flat in θ, is carried by the
   surroundings; there a measured slope, a magnitude, is biased upwards by its noise, so
   the target is the slope whose folded-normal mean is the measurement); normals from
   the height field, with θ blended by precision;
5. thickness at the final angle: the linear θ-d coupling of the fit near the fitted angle,
   a refit where the angle moved further.
"""

from __future__ import annotations

import time

import numpy as np

from thinfilm.core.io import Estimate

from . import eikonal as _eik
from . import spectral_model as _sm
from .peaks import PEAK_NONE, PEAK_OK, PEAK_SEVERAL
from .spectral_fit import angle_thickness_lm, estimate_film_ior_either_side, extrema_angles, fit_no_peak, \
    index_thickness_sigma, initial_thickness, sigma_theta, thickness_at, thickness_limits

__all__ = ["reconstruct_eikonal", "unfold_magnitude"]


def unfold_magnitude(observed, sigma):
    """The ``μ >= 0`` whose folded normal ``|N(μ, σ²)|`` has mean ``observed`` (0 below the mean
    of ``|N(0, σ²)|``, σ sqrt(2/π)); ``observed`` itself beyond 8 σ, where the fold is nil."""
    from scipy.special import erf

    t = np.linspace(0.0, 8.0, 1601)
    mean = np.sqrt(2.0 / np.pi) * np.exp(-0.5 * t * t) + t * erf(t / np.sqrt(2.0))
    x = np.asarray(observed, dtype=np.float64)
    s = np.maximum(np.asarray(sigma, dtype=np.float64), 1e-300)
    with np.errstate(invalid="ignore", over="ignore"):
        r = np.nan_to_num(x / s, nan=0.0, posinf=np.inf)
        return np.where(r >= mean[-1], x, s * np.interp(np.minimum(r, mean[-1]), mean, t, left=0.0))


def reconstruct_eikonal(cube, wavelengths_nm, substrate_ior, mask, smoothness=10.0, angle_floor_deg=0.2,
                        condition_scale=2.0, noise_scale=1.0, misfit=3.0, direction_weight=0.1, anchor_weight=1.0,
                        thickness_range_nm=None, band_fwhm_nm=0.0):
    """The s-spectrum method (see the module docstring).

    ``thickness_range_nm``: the film thicknesses considered (default
    :data:`thinfilm.core.bands.SPECTRAL_THICKNESS_RANGE_NM`, less where the bands of width
    ``band_fwhm_nm`` cannot resolve the fringes: then one warning says so).
    """
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    n3 = float(substrate_ior)
    limits = thickness_limits(wl, thickness_range_nm, band_fwhm_nm)
    t = {}
    # 1. the film index, once for the object, below or above the substrate's (which side
    # holds is read from the spectra: the extrema at the bare substrate's reflectance are
    # maxima below it, minima above it)
    t0 = time.perf_counter()
    spectra = np.asarray(np.asarray(cube)[mask], dtype=np.float64)
    n2, n2_info = estimate_film_ior_either_side(spectra, wl, n3, limits=limits)
    limits.warn_if_cut(n2)
    t["film_ior"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    pk, theta_peak = extrema_angles(spectra, wl, n3, n2_info["film_ior_above_substrate"])
    stats = {"peak_one": int(np.sum(pk.status == PEAK_OK)), "peak_several": int(np.sum(pk.status == PEAK_SEVERAL)),
             "peak_none": int(np.sum(pk.status == PEAK_NONE))}
    t["peaks"] = time.perf_counter() - t0

    # 2. (θ, d) per pixel. The capture is S0 + sqrt(S1² + S2²); its noise bias is modelled
    # with the S1/S2 noise of a four-angle rotating polarizer, about the band noise of the
    # s spectrum where the light is barely polarized (where the bias matters)
    t0 = time.perf_counter()
    stokes_noise = noise_scale * pk.noise
    has = np.isfinite(theta_peak)
    d0 = np.full(theta_peak.shape, np.nan)
    if has.any():
        d0[has] = initial_thickness(spectra[has], theta_peak[has], pk.wavelength_nm[has], n2, n3, wl, limits=limits)
    th0 = np.where(has, theta_peak, 0.0)
    # pixels with a peak first; they seed the others
    th_fit = np.zeros_like(th0)
    d_fit = np.zeros_like(th0)
    neq = np.zeros((th0.size, 6))  # normal equations at the fit, [a11 a12 a22 g1 g2 sse]
    if has.any():
        th_fit[has], d_fit[has], neq[has] = angle_thickness_lm(
            spectra[has], th0[has], d0[has], n2, n3, wl, stokes_noise=stokes_noise[has])
    none = ~has
    if none.any():
        th_fit[none], d_fit[none], neq[none] = fit_no_peak(
            spectra, mask, has, th_fit, d_fit, n2, n3, wl, stokes_noise, misfit=misfit)
    # a pixel whose fit from its peak stays far above the noise read a wrong peak (one of
    # several, or a noise bump), and so a wrong order and angle (thickness errors of a
    # quarter to half a micron), and pixels without a peak started from such a pixel inherit
    # its order. For the thickness, those pixels are refitted from the nearest well-fitted
    # pixel (and the coarse grid), keeping the better of the two fits. The surface keeps the
    # first fits, where a large residual already gives the angle a low weight: feeding the
    # refitted angles to the surface solve as well changed the mean normal error of 48 px
    # hemispheres and cylinders by up to ±0.3°, either way depending on the seed
    th_surf, neq_surf = th_fit.copy(), neq.copy()
    poor = has & (neq[:, 5] > misfit * wl.size * np.maximum(stokes_noise, 1e-6) ** 2)
    if poor.any() and (has & ~poor).any():
        redo = poor | none
        th_r, d_r, neq_r = fit_no_peak(spectra, mask, has & ~poor, th_fit, d_fit, n2, n3, wl, stokes_noise,
                                        misfit=misfit, which=redo)
        better = neq_r[:, 5] < neq[redo, 5]
        idx = np.nonzero(redo)[0][better]
        th_fit[idx], d_fit[idx], neq[idx] = th_r[better], d_r[better], neq_r[better]
    stats["refit_poor_peak"] = int(poor.sum())
    sig = sigma_theta(neq_surf, wl.size)
    t["fit_angle_thickness"] = time.perf_counter() - t0

    # 3. the surface as a whole
    t0 = time.perf_counter()
    theta_img = np.zeros(mask.shape)
    theta_img[mask] = th_surf
    # precision of each pixel's angle: the fit's own, and the conditioning of the peak
    # reflectance in θ (flat at normal incidence) at the pixel's noise level, which also covers
    # the noise bias of S0 + sqrt(S1² + S2²) where the light is barely polarized
    h = np.radians(0.05)
    slope_R = np.abs(_sm.peak_reflectance(th_surf + h, n3) - _sm.peak_reflectance(np.maximum(th_surf - h, 0), n3)) \
        / (th_surf + h - np.maximum(th_surf - h, 0))
    sig_cond = condition_scale * pk.noise / np.maximum(slope_R, 1e-12)
    sig_img = np.full(mask.shape, np.inf)
    sig_img[mask] = np.maximum(np.hypot(sig, sig_cond), np.radians(angle_floor_deg))
    slope = np.tan(theta_img)
    sig_slope = sig_img / np.cos(np.minimum(theta_img, np.radians(89.0))) ** 2
    weight = np.where(mask, 1.0 / sig_slope ** 2, 0.0)
    phi, seed_kind = _eik.seed_level(theta_img, mask)
    z0 = _eik.fast_marching_height(slope, mask, phi)
    t["fast_marching"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    # the refinement's target slope: a measured angle is a magnitude, so near normal incidence
    # (σ comparable to the slope) its noise only ever adds to it; the target is the slope
    # whose folded-normal mean is the measurement
    slope_t = np.where(mask, unfold_magnitude(slope, np.where(mask, sig_slope, 1.0)), 0.0)
    # started from the silhouette (no occluding band: flat faces meeting a ground edge), the
    # surface keeps the fast march's gradient directions and the silhouette's height; a dome
    # started from its steep band is smoothed freely (the march's directions are poor where
    # its fronts meet, at the top)
    flat = seed_kind == "silhouette"
    z = _eik.refine_height(z0, slope_t, weight, mask, smoothness=smoothness,
                           direction_weight=direction_weight if flat else 0.0,
                           anchors=mask & (phi <= 0) if flat else None, anchor_weight=anchor_weight)
    z -= np.nanmax(z)
    p, q = _eik.height_gradient(z, mask)
    theta_z = np.arctan(np.hypot(p, q))
    # blend: the pixel's own angle where it is precise, the surface's elsewhere
    sig_z = SURFACE_SIGMA_RAD
    w_d = 1.0 / sig_img ** 2
    w_z = 1.0 / sig_z ** 2
    theta_fin = (w_d * theta_img + w_z * theta_z) / (w_d + w_z)
    g = np.hypot(p, q)
    ux = np.where(g > 0, p / np.where(g > 0, g, 1), 0.0)
    uy = np.where(g > 0, q / np.where(g > 0, g, 1), 0.0)
    st = np.tan(np.minimum(theta_fin, np.radians(89.9)))
    normals = _eik.gradient_to_normals(st * ux, st * uy)
    t["refine_surface"] = time.perf_counter() - t0

    # 4. thickness at the final angle
    t0 = time.perf_counter()
    d_fin = thickness_at(spectra, theta_fin[mask], th_fit, d_fit, neq, n2, n3, wl, stokes_noise)
    t["thickness"] = time.perf_counter() - t0
    thickness = np.full(mask.shape, np.nan)
    thickness[mask] = d_fin
    sig_n, sig_d = _uncertainty(mask, sig_img, theta_img, theta_z, neq, wl.size)
    sig_d[mask] = np.hypot(sig_d[mask], index_thickness_sigma(d_fin, theta_fin[mask], n2))
    valid = mask & np.isfinite(thickness) & np.isfinite(z)
    info = {"peaks": stats, "timings_s": t, **n2_info, "capture": "s",
            "seeds": seed_kind, "smoothness": smoothness,
            "thickness_range_nm": [limits.lo, limits.upper(n2)]}
    return Estimate(normals=normals, thickness_nm=thickness, valid=valid, film_ior=float(n2),
                    substrate_ior=float(substrate_ior), height=z, info=info, normal_sigma_deg=sig_n,
                    thickness_sigma_nm=sig_d)


#: the blend scale of step 3 (radians): the weight of the refined surface's zenith against each
#: pixel's own
SURFACE_SIGMA_RAD = float(np.radians(1.0))

#: side of the window (pixels) over which the surface's own error is measured
SURFACE_ERROR_WINDOW = 9

#: pixels whose own angle is known better than this (radians) measure the surface's error
PRECISE_ANGLE_RAD = float(np.radians(0.5))


def surface_angle_sigma(mask, sig_img, theta_img, theta_z, window=SURFACE_ERROR_WINDOW):
    """The refined surface's angular error (radians, (H, W)), measured where the data are
    precise: the local mean square of ``theta_img - theta_z`` less the pixels' own variance,
    over a ``window``-pixel square of the pixels whose angle is known to
    :data:`PRECISE_ANGLE_RAD`. Pixels with none near take the largest local value of the
    object (a surface carried over a region where the spectra say little is as uncertain as
    its worst-measured part)."""
    from scipy.ndimage import uniform_filter

    precise = mask & (sig_img < PRECISE_ANGLE_RAD) & np.isfinite(theta_z)
    r2 = np.where(precise, (theta_img - np.nan_to_num(theta_z)) ** 2, 0.0)
    s2 = np.where(precise, sig_img ** 2, 0.0)
    w = uniform_filter(precise.astype(np.float64), window, mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):
        local = (uniform_filter(r2, window, mode="constant") - uniform_filter(s2, window, mode="constant")) / w
    enough = mask & (w * window * window >= 5)
    local = np.sqrt(np.clip(np.nan_to_num(local), 0.0, None))
    worst = float(np.max(local[enough])) if enough.any() else SURFACE_SIGMA_RAD
    return np.where(enough, np.maximum(local, np.radians(0.05)), worst)


def _uncertainty(mask, sig_img, theta_img, theta_z, neq, bands):
    """Each pixel's ``(normal σ in degrees, thickness σ in nm)`` (H, W). The zenith: the
    precision-weighted blend of the pixel's own angle (σ ``sig_img``) and the surface's
    (:func:`surface_angle_sigma`); across the gradient, where the s spectra say nothing, the
    surface's error alone (taken as isotropic). The thickness: its variance at fixed angle
    from the fit's normal equations ``neq`` ([a11 a12 a22 g1 g2 sse], the noise from the
    residuals), plus what the final angle's σ carries through the fit's θ-d coupling."""
    sig_s = surface_angle_sigma(mask, sig_img, theta_img, theta_z)[mask]
    sig_theta = 1.0 / np.sqrt(1.0 / sig_img[mask] ** 2 + 1.0 / sig_s ** 2)
    sig_n = np.full(mask.shape, np.nan)
    sig_n[mask] = np.degrees(np.hypot(sig_theta, sig_s))
    var = neq[:, 5] / max(bands - 2, 1)
    a12, a22 = neq[:, 1], np.maximum(neq[:, 2], 1e-300)
    sig_d = np.full(mask.shape, np.nan)
    sig_d[mask] = np.sqrt(var / a22 + (a12 / a22) ** 2 * sig_theta ** 2)
    return sig_n, sig_d
