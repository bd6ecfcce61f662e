"""The Cramér-Rao bound of a pixel: how well any unbiased estimator can know its normal and
its film thickness from a capture, given the rig, the film and the camera noise.

For a pixel with unknowns ``x = (v1, v2, d_1 … d_L)`` (the observation model's
``double_angle`` parametrization, :data:`thinfilm.core.model.PARAMETRIZATIONS`: ``(v1, v2) =
sin² θ (cos 2φ, sin 2φ)``, smooth through normal incidence, and each layer's thickness), the
captured values ``y_m`` are independent with means ``μ_m(x)`` (the observation model) and
variances ``σ_m²`` (the camera noise model, :func:`thinfilm.core.noise.capture_variance`, at
the exposures the generator's auto exposure picks for the noise-free images). Their Fisher
information is

    F = Σ_m (∂μ_m/∂x)(∂μ_m/∂x)ᵀ / σ_m²,

with the derivatives by the observation model's automatic differentiation, and every
unbiased estimate has covariance at least ``F⁻¹``. Reported per pixel:

``thickness_nm``
    ``sqrt((F⁻¹)_dd)`` for each layer (a standard deviation);
``normal_deg``
    the RMS angle between the estimated and the true normal, ``sqrt(trace(J C Jᵀ))`` with ``C``
    the (v1, v2) block of ``F⁻¹`` and ``J = ∂n/∂(v1, v2)``, in degrees (infinite from the s
    spectra alone, which do not depend on the azimuth);
``zenith_deg``
    the standard deviation of the zenith, in degrees.

What is measured depends on the capture an estimator uses:

``polarized_rgb``
    the polarization camera's RGB images, one per polarizer angle (3 values each);
``stokes``
    the hyperspectral camera's images, one per band and polarizer angle (the Stokes cube is a
    linear fit to them, which keeps their information);
``spectral_s``
    the s spectra ``S0 + |(S1, S2)|`` alone (their variance propagated from those images).

The bound holds for the index known; an estimator that also fits it can do no better. Near
normal incidence (θ → 0) the azimuth, and at grazing angles the zenith, are barely seen: the
per-pixel bound on the normal grows without limit there, and a biased estimator (a surface
prior) beats it, so comparisons use pixels of moderate zenith (:data:`ZENITH_RANGE_DEG`).

Examples
--------
>>> from thinfilm.core.film import Film
>>> from thinfilm.core.model import Rig
>>> rig = Rig(wavelengths_nm=tuple(np.arange(400.0, 721.0, 20.0)))
>>> n = np.array([[np.sin(0.6), 0.0, np.cos(0.6)]])
>>> noise = {"model": "camera", "full_well": 10000.0, "read_noise": 5.0, "bits": 12, "exposure": "auto"}
>>> b = pixel_bound(rig, Film.single(1.37, substrate_ior=1.6), n, np.array([400.0]), noise, "stokes")
>>> bool(0.0 < b["normal_deg"][0] < 1.0 and 0.0 < b["thickness_nm"][0, 0] < 5.0)
True
"""

from __future__ import annotations


import numpy as np

from .conventions import stokes_design_matrix
from .model import ObservationModel, state_from_normals, view_frames
from .noise import capture_variance, exposure_gains

__all__ = ["CAPTURES", "ZENITH_RANGE_DEG", "double_angle_from_normals", "normal_jacobian", "image_plane_jacobian",
           "angle_sigma_deg", "estimate_capture", "pixel_bound"]

#: the captures a bound is computed for
CAPTURES = ("polarized_rgb", "stokes", "spectral_s")

#: true zenith range (degrees) of the pixels on which a bound and the errors are compared
ZENITH_RANGE_DEG = (15.0, 75.0)


def double_angle_from_normals(normals) -> np.ndarray:
    """``(v1, v2) = sin² θ (cos 2φ, sin 2φ)`` (N, 2) of unit normals (N, 3) seen by the
    orthographic camera (view +z, reference axis +x)."""
    n = np.asarray(normals, dtype=np.float64)
    u = np.clip(1.0 - n[:, 2] ** 2, 0.0, 1.0)
    phi = np.arctan2(n[:, 1], n[:, 0])
    return np.stack([u * np.cos(2 * phi), u * np.sin(2 * phi)], axis=1)


def normal_jacobian(v) -> np.ndarray:
    """``∂n/∂(v1, v2)`` (N, 3, 2) of the normal ``n = (sin θ cos φ, sin θ sin φ, cos θ)`` with
    ``sin² θ = |v|`` and ``φ = ½ atan2(v2, v1)`` (either of the two azimuths: the angle is the
    same)."""
    v = np.asarray(v, dtype=np.float64)
    u = np.hypot(v[:, 0], v[:, 1])
    phi = 0.5 * np.arctan2(v[:, 1], v[:, 0])
    s, c = np.sqrt(u), np.sqrt(np.clip(1.0 - u, 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        dn_du = np.stack([np.cos(phi) / (2 * s), np.sin(phi) / (2 * s), -1.0 / (2 * c)], axis=1)
        dn_dphi = np.stack([-s * np.sin(phi), s * np.cos(phi), np.zeros_like(s)], axis=1)
        du_dv = v / u[:, None]
        dphi_dv = 0.5 * np.stack([-v[:, 1], v[:, 0]], axis=1) / (u * u)[:, None]
    return dn_du[:, :, None] * du_dv[:, None, :] + dn_dphi[:, :, None] * dphi_dv[:, None, :]


def image_plane_jacobian(nxy) -> np.ndarray:
    """``∂n/∂(a, b)`` (N, 3, 2) of the unit normal ``n = (a, b, sqrt(1 - a² - b²))`` with
    image-plane part ``(a, b)`` (N, 2)."""
    nxy = np.asarray(nxy, dtype=np.float64)
    nz = np.sqrt(np.clip(1.0 - np.sum(nxy ** 2, axis=1), 1e-12, 1.0))
    J = np.zeros((nxy.shape[0], 3, 2))
    J[:, 0, 0] = J[:, 1, 1] = 1.0
    J[:, 2, :] = -nxy / nz[:, None]
    return J


def angle_sigma_deg(jacobian, cov) -> np.ndarray:
    """The RMS angle (degrees) between a unit normal and its estimate, ``sqrt(trace(J C Jᵀ))``,
    of a normal whose parameters have covariance ``cov`` (N, P, P) and Jacobian ``∂n/∂p``
    (N, 3, P) (:func:`normal_jacobian`, :func:`image_plane_jacobian`); NaN where ``cov`` is."""
    var = np.einsum("nip,npq,niq->n", jacobian, cov, jacobian)
    with np.errstate(invalid="ignore"):
        return np.degrees(np.sqrt(np.maximum(var, 0.0) + np.where(np.isnan(var), np.nan, 0.0)))


def estimate_capture(estimate, dataset) -> str:
    """The capture an estimate was made from: ``stokes``, ``spectral_s`` or ``polarized_rgb``
    (its ``capture`` entry, else its method's kind, else what the dataset holds)."""
    from . import registry

    cap = estimate.info.get("capture")
    if cap in ("stokes", "s", "spectral_s", "polarized_rgb"):
        return {"s": "spectral_s"}.get(cap, cap)
    method = str(estimate.info.get("method") or "").removesuffix("+refine")
    kinds = {m.kind for m in registry.methods() if method in (m.name, *m.aliases)}
    if kinds == {"rgb"} or (not kinds and dataset.polarized_rgb and dataset.spectral_s is None):
        return "polarized_rgb"
    return "spectral_s" if kinds == {"spectral"} or not dataset.stokes else "stokes"


def _gains(images, noise):
    """Auto (or fixed) exposure gains of noise-free images (M, P[, 3]) over the object's
    pixels P, as the generator exposes them (:func:`thinfilm.core.noise.exposure_gains`)."""
    imgs = images[:, None]  # (M, 1, P[, 3]): one image row per exposure
    return exposure_gains(imgs, np.ones(imgs.shape[1:3], dtype=bool), noise)


def pixel_bound(rig, film, normals, thickness_nm, noise: dict, capture: str, backend: str = "llvm",
                chunk: int = 4096) -> dict:
    """The per-pixel Cramér-Rao bound (module docstring) of the object's pixels.

    Parameters
    ----------
    rig : :class:`thinfilm.core.model.Rig`
    film : :class:`thinfilm.core.film.Film`
    normals : (N, 3) true unit normals of the object's pixels (all of them: auto exposure
        looks at the brightest).
    thickness_nm : (N,) or (N, L) their true thicknesses.
    noise : the dataset's ``[noise]`` table (``meta.json``), model ``camera``.
    capture : one of :data:`CAPTURES`.

    Returns
    -------
    dict ``normal_deg`` (N,), ``zenith_deg`` (N,), ``thickness_nm`` (N, L), ``fisher`` (N, P, P)
    (P = 2 + L; 1 + L for ``spectral_s``, whose unknowns are ``(|v|, d…)``); NaN where the
    pixel gets no light or its information is singular.
    """
    if capture not in CAPTURES:
        raise ValueError(f"capture must be one of {CAPTURES}, got {capture!r}")
    if noise.get("model") != "camera":
        raise ValueError("the bound needs the camera noise model (noise model 'none' has no noise)")
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    N = normals.shape[0]
    model = ObservationModel(rig, film, backend=backend)
    L = model.layers
    d = _layers(model, thickness_nm, N)
    views, e1 = view_frames(rig, (1, N))
    light = state_from_normals(normals, views.reshape(-1, 3), e1.reshape(-1, 3), [d[:, 0]],
                               rig.dome_hole_deg).light
    x = np.concatenate([double_angle_from_normals(normals), d], axis=1)
    kind = "polarized_rgb" if capture == "polarized_rgb" else "stokes"
    angles = np.radians(np.asarray(rig.polarizer_angles_deg, dtype=np.float64))
    design = stokes_design_matrix(np.degrees(angles))                      # (A, 3): I = design @ S
    B = len(rig.wavelengths_nm)
    # the exposures first: each image's brightest object pixel (values alone, every pixel)
    vals = np.concatenate([model.evaluate(kind, x[s:s + chunk], "double_angle", fixed={"light": light[s:s + chunk]})
                           for s in range(0, N, chunk)])
    if capture == "polarized_rgb":
        imgs = vals.reshape(N, -1, 3).transpose(1, 0, 2)                   # (A, N, 3)
        gains = _gains(imgs, noise)                                        # (A,)
    else:
        imgs = np.einsum("ak,nkb->anb", design, vals.reshape(N, 3, B))     # (A, N, B)
        gains = np.stack([_gains(imgs[:, :, b], noise) for b in range(B)], axis=1)  # (A, B)
    del vals, imgs
    F = np.concatenate([_fisher(model, kind, capture, x[s:s + chunk], light[s:s + chunk], gains, design, noise)
                        for s in range(0, N, chunk)])
    cov = np.full_like(F, np.nan)
    ok = np.all(np.isfinite(F), axis=(1, 2)) & (light > 0)
    ok[ok] &= np.linalg.cond(F[ok]) < 1e14
    cov[ok] = np.linalg.inv(F[ok])
    u = np.hypot(x[:, 0], x[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        dtheta_du = 1.0 / (2.0 * np.sqrt(u * (1.0 - u)))                   # θ = asin(sqrt(u))
        if capture == "spectral_s":
            normal_var = np.where(ok, np.inf, np.nan)  # the azimuth is not in the s spectra
            zenith_var = dtheta_du ** 2 * cov[:, 0, 0]
        else:
            Jn = normal_jacobian(x[:, :2])
            normal_var = np.einsum("nip,npq,niq->n", Jn, cov[:, :2, :2], Jn)
            g = dtheta_du[:, None] * x[:, :2] / u[:, None]                  # ∂θ/∂(v1, v2)
            zenith_var = np.einsum("np,npq,nq->n", g, cov[:, :2, :2], g)
        first = 1 if capture == "spectral_s" else 2
        thick = np.sqrt(np.einsum("nii->ni", cov[:, first:, first:]))
        normal_deg = np.degrees(np.sqrt(normal_var))
        zenith_deg = np.degrees(np.sqrt(zenith_var))
    return {"normal_deg": normal_deg, "zenith_deg": zenith_deg, "thickness_nm": thick, "fisher": F}


def _fisher(model, kind, capture, x, light, gains, design, noise) -> np.ndarray:
    """Fisher information (n, P, P) of the pixels ``x`` (n, 2+L) for ``capture``, the images
    exposed with ``gains`` ((A,) camera images, or (A, B) one per angle and band)."""
    n = x.shape[0]
    vals, jac = model.evaluate(kind, x, "double_angle", fixed={"light": light}, derivatives=True)
    if capture == "polarized_rgb":
        A = gains.size
        imgs = vals.reshape(n, A, 3).transpose(1, 0, 2)                   # (A, n, 3)
        var = capture_variance(imgs, gains, noise)                         # (A, n, 3)
        J = jac.reshape(n, A * 3, -1)
        w = 1.0 / var.transpose(1, 0, 2).reshape(n, A * 3)
        return np.einsum("nmp,nm,nmq->npq", J, w, J)
    B = gains.shape[1]
    S = vals.reshape(n, 3, B)
    dS = jac.reshape(n, 3, B, -1)
    imgs = np.einsum("ak,nkb->anb", design, S)                             # (A, n, B)
    var = np.stack([capture_variance(imgs[:, :, b], gains[:, b], noise) for b in range(B)], axis=2)
    if capture == "stokes":
        J = np.einsum("ak,nkbp->nabp", design, dS).reshape(n, -1, dS.shape[-1])
        w = 1.0 / var.transpose(1, 0, 2).reshape(n, -1)
        return np.einsum("nmp,nm,nmq->npq", J, w, J)
    # s = S0 + |(S1, S2)| of the fitted Stokes vector: its derivatives by the images
    fit = np.linalg.pinv(design)                                           # (3, A)
    lin = np.hypot(S[:, 1], S[:, 2])                                       # (n, B)
    safe = np.where(lin > 0, lin, 1.0)
    u1, u2 = np.where(lin > 0, S[:, 1] / safe, 0.0), np.where(lin > 0, S[:, 2] / safe, 0.0)
    ds_dI = fit[0][:, None, None] + u1[None] * fit[1][:, None, None] + u2[None] * fit[2][:, None, None]
    w = 1.0 / np.sum(ds_dI ** 2 * var, axis=0)                            # (n, B)
    J = dS[:, 0] + u1[:, :, None] * dS[:, 1] + u2[:, :, None] * dS[:, 2]
    # s does not depend on the azimuth: its information is in (|v|, d) alone
    u = np.hypot(x[:, 0], x[:, 1])
    safe_u = np.where(u > 0, u, 1.0)
    cos2, sin2 = np.where(u > 0, x[:, 0] / safe_u, 1.0), np.where(u > 0, x[:, 1] / safe_u, 0.0)
    J = np.concatenate([(J[:, :, 0] * cos2[:, None] + J[:, :, 1] * sin2[:, None])[:, :, None], J[:, :, 2:]], axis=2)
    return np.einsum("nmp,nm,nmq->npq", J, w, J)


def _layers(model, thickness_nm, n) -> np.ndarray:
    d = np.asarray(thickness_nm, dtype=np.float64)
    if d.ndim == 1:
        d = d[:, None]
    if d.shape != (n, model.layers):
        raise ValueError(f"thickness_nm must be ({n},) or ({n}, {model.layers}), got {d.shape}")
    return d
