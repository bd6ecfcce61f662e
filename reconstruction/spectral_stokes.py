"""Per-pixel fits of the linear Stokes cube of a rotating-polarizer hyperspectral capture.

A specular pixel of zenith θ and azimuth φ (orthographic camera) reflects the unpolarized
dome as ``S0 = (R_s + R_p)/2``, ``(S1, S2) = -P (cos 2φ, sin 2φ)`` with ``P = (R_s - R_p)/2``
(:func:`thinfilm.core.conventions.specular_stokes`) at every band, ``R_s`` and ``R_p`` from
the optics core. The unknowns of a pixel are carried as ``x = (v1, v2, d)`` with
``(v1, v2) = u (cos 2φ, sin 2φ)`` and ``u = sin² θ``: then ``(S1, S2) = -Q(u, d) (v1, v2)``
with ``Q = P / u``, smooth through normal incidence, where φ is undefined (the
parameterization of the polarized-RGB inversion, :mod:`.rgb_invert`). The angle of
polarization fixes φ modulo 180°, and the s and p spectra together fix θ at every pixel:
with the film index known, each pixel's zenith, azimuth axis and thickness come from one
least-squares fit to all 3 B values.

:func:`stokes_normal_equations` evaluates the model and its Gauss-Newton normal equations
for many pixels at once: on Dr.Jit's LLVM backend one fused kernel over pixels × bands
(forward-mode derivatives, sums over bands in the kernel), else on NumPy by central
differences. :func:`fit_stokes_pixels` runs the batched Levenberg-Marquardt of :mod:`.lm`
on it.

The noise of the Stokes fit of a four-angle rotating polarizer (0, 45, 90, 135°) is
``σ(S1) = σ(S2) = √2 σ(S0)``; the residuals are weighted accordingly (``w1 = w0 / √2``).
"""

from __future__ import annotations

import numpy as np

from thinfilm.bsdf import optics

from .lm import levenberg_marquardt
from .spectral_model import drjit_available

__all__ = ["U_MAX", "stokes_model", "stokes_normal_equations", "fit_stokes_pixels", "axis_from_stokes",
           "x_to_angles", "angles_to_x"]

#: largest ``u = sin² θ`` a fit may reach (θ = 89.5°)
U_MAX = float(np.sin(np.radians(89.5)) ** 2)
_U_EPS = 1e-9
_CHUNK = 1 << 21  # pixels × bands per kernel


def angles_to_x(theta_rad, phi_rad, thickness_nm):
    """``(v1, v2, d)`` (N, 3) from zenith, azimuth (radians) and thickness."""
    u = np.sin(np.asarray(theta_rad, dtype=np.float64)) ** 2
    phi = np.asarray(phi_rad, dtype=np.float64)
    return np.stack([u * np.cos(2 * phi), u * np.sin(2 * phi), np.asarray(thickness_nm, dtype=np.float64)], -1)


def x_to_angles(x):
    """Zenith (radians), azimuth modulo π (radians, in [0, π)) and thickness of ``x``."""
    u = np.clip(np.hypot(x[:, 0], x[:, 1]), 0.0, 1.0)
    return np.arcsin(np.sqrt(u)), np.mod(0.5 * np.arctan2(x[:, 1], x[:, 0]), np.pi), x[:, 2]


def axis_from_stokes(S1, S2, weights=None):
    """Azimuth modulo π (radians) from the linear Stokes spectra (N, B) of specular pixels.

    The points ``(S1, S2)`` of all bands lie on one line through the origin at angle 2φ + π
    (``P`` may change sign between bands); its direction is the principal axis of their
    second moments, and ``P`` positive on balance (``R_s > R_p``, as on dielectrics) picks
    which of the two perpendicular candidates it is.

    Returns
    -------
    phi : (N,) radians in [0, π); strength : (N,) the polarized signal along the axis
    (``Σ_b P_b`` along the chosen direction, >= 0).
    """
    S1 = np.asarray(S1, dtype=np.float64)
    S2 = np.asarray(S2, dtype=np.float64)
    w = 1.0 if weights is None else weights
    beta = 0.5 * np.arctan2(2.0 * np.sum(w * S1 * S2, axis=-1), np.sum(w * (S1 * S1 - S2 * S2), axis=-1))
    proj = np.sum(w * (S1 * np.cos(beta)[..., None] + S2 * np.sin(beta)[..., None]), axis=-1)
    # along beta the points are P (cos(2φ + π), sin(2φ + π)): 2φ = beta - π where Σ P > 0
    two_phi = np.where(proj > 0, beta - np.pi, beta)
    return np.mod(0.5 * two_phi, np.pi), np.abs(proj)


def stokes_model(u, thickness_nm, film_ior, substrate_ior, wavelengths_nm):
    """``S0`` and ``Q = P / u`` (N, B) of pixels with ``u = sin² θ`` and thickness (N,), by
    the optics core (NumPy)."""
    u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
    c = np.sqrt(1.0 - u)[:, None]
    n2 = np.broadcast_to(np.asarray(film_ior, dtype=np.float64), u.shape)[:, None]
    Rs, Rp = optics.reflectances(c, np.asarray(wavelengths_nm, dtype=np.float64)[None, :],
                                 np.asarray(thickness_nm, dtype=np.float64)[:, None], n2, substrate_ior)
    return 0.5 * (Rs + Rp), 0.5 * (Rs - Rp) / np.maximum(u, _U_EPS)[:, None]


def stokes_normal_equations(S0, S1, S2, x, film_ior, substrate_ior, wavelengths_nm, w0=1.0, w1=None):
    """Gauss-Newton normal equations of the Stokes model at ``x`` for N pixels.

    Residuals per band: ``w0 (S0 - S0(u, d))``, ``w1 (S1 + Q v1)``, ``w1 (S2 + Q v2)``.

    Parameters
    ----------
    S0, S1, S2 : (N, B) measured Stokes spectra.
    x : (N, 3) ``(v1, v2, d)``.
    film_ior : float or (N,); substrate_ior : float.
    w0, w1 : float or (N,) residual weights (``w1`` defaults to ``w0 / √2``).

    Returns
    -------
    H : (N, 3, 3) ``JᵀJ``; g : (N, 3) ``Jᵀr`` (J the Jacobian of the residuals); cost : (N,)
    ``Σ r²``.
    """
    S0, S1, S2 = (np.asarray(a, dtype=np.float64) for a in (S0, S1, S2))
    x = np.asarray(x, dtype=np.float64)
    n, b = S0.shape
    w0 = np.broadcast_to(np.asarray(w0, dtype=np.float64), (n,))
    w1 = w0 / np.sqrt(2.0) if w1 is None else np.broadcast_to(np.asarray(w1, dtype=np.float64), (n,))
    n2 = np.broadcast_to(np.asarray(film_ior, dtype=np.float64), (n,))
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    H = np.empty((n, 3, 3))
    g = np.empty((n, 3))
    cost = np.empty(n)
    rows = max(1, _CHUNK // max(b, 1))
    kernel = _dr_neq if drjit_available() else _np_neq
    for s in range(0, n, rows):
        e = min(n, s + rows)
        sums = kernel(S0[s:e], S1[s:e], S2[s:e], x[s:e], n2[s:e], float(substrate_ior), wl, w0[s:e], w1[s:e])
        h00, h01, h02, h11, h12, h22, g0, g1, g2, c = sums
        H[s:e] = np.stack([np.stack([h00, h01, h02], -1), np.stack([h01, h11, h12], -1),
                           np.stack([h02, h12, h22], -1)], -2)
        g[s:e] = np.stack([g0, g1, g2], -1)
        cost[s:e] = c
    return H, g, cost


def _residual_parts(O0, O1, O2, S0m, Q, S0u, Qu, S0d, Qd, V1, V2, E1, E2, w0, w1):
    """Residuals and their Jacobian rows (backend-generic): returns (r0, r1, r2) and the
    three rows (∂r/∂v1, ∂r/∂v2, ∂r/∂d) of each."""
    r0 = w0 * (O0 - S0m)
    r1 = w1 * (O1 + Q * V1)
    r2 = w1 * (O2 + Q * V2)
    J0 = (-w0 * S0u * E1, -w0 * S0u * E2, -w0 * S0d)
    J1 = (w1 * (Q + Qu * E1 * V1), w1 * (Qu * E2 * V1), w1 * (Qd * V1))
    J2 = (w1 * (Qu * E1 * V2), w1 * (Q + Qu * E2 * V2), w1 * (Qd * V2))
    return (r0, r1, r2), (J0, J1, J2)


def _products(r, J):
    """The 10 band terms of the normal equations: H (upper triangle), g, cost."""
    out = []
    for a, c in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)):
        out.append(sum(Jk[a] * Jk[c] for Jk in J))
    for a in range(3):
        out.append(sum(Jk[a] * rk for Jk, rk in zip(J, r)))
    out.append(sum(rk * rk for rk in r))
    return out


def _np_neq(O0, O1, O2, x, n2, n3, wl, w0, w1):
    u = np.hypot(x[:, 0], x[:, 1])
    d = x[:, 2]
    S0m, Q = stokes_model(u, d, n2, n3, wl)
    hu, hd = 1e-6, 1e-3
    up, um = np.minimum(u + hu, 1.0), np.maximum(u - hu, 0.0)
    a, b_ = stokes_model(up, d, n2, n3, wl), stokes_model(um, d, n2, n3, wl)
    du = (up - um)[:, None]
    S0u, Qu = (a[0] - b_[0]) / du, (a[1] - b_[1]) / du
    a, b_ = stokes_model(u, d + hd, n2, n3, wl), stokes_model(u, d - hd, n2, n3, wl)
    S0d, Qd = (a[0] - b_[0]) / (2 * hd), (a[1] - b_[1]) / (2 * hd)
    us = np.where(u > _U_EPS, u, 1.0)
    E1 = np.where(u > _U_EPS, x[:, 0] / us, 0.0)[:, None]
    E2 = np.where(u > _U_EPS, x[:, 1] / us, 0.0)[:, None]
    r, J = _residual_parts(O0, O1, O2, S0m, Q, S0u, Qu, S0d, Qd, x[:, :1], x[:, 1:2], E1, E2,
                           w0[:, None], w1[:, None])
    return [np.sum(t, axis=1) for t in _products(r, J)]


def _dr_neq(O0, O1, O2, x, n2, n3, wl, w0, w1):
    import drjit as dr
    from drjit.llvm.ad import Float64, UInt32

    n, b = O0.shape
    idx = dr.arange(UInt32, n * b)
    pix = idx // b
    band = idx - pix * b
    u = np.hypot(x[:, 0], x[:, 1])
    us = np.where(u > _U_EPS, u, 1.0)
    per_pixel = {
        "u": np.minimum(u, 1.0), "d": x[:, 2], "v1": x[:, 0], "v2": x[:, 1], "n2": n2,
        "e1": np.where(u > _U_EPS, x[:, 0] / us, 0.0), "e2": np.where(u > _U_EPS, x[:, 1] / us, 0.0),
        "w0": w0, "w1": w1,
    }
    P = {k: dr.gather(Float64, Float64(np.ascontiguousarray(v, dtype=np.float64)), pix) for k, v in per_pixel.items()}
    W = dr.gather(Float64, Float64(wl), band)
    O = [Float64(np.ascontiguousarray(o, dtype=np.float64).ravel()) for o in (O0, O1, O2)]
    U, D = P["u"], P["d"]
    dr.enable_grad(U, D)
    Rs, Rp = optics.reflectances(dr.sqrt(dr.maximum(1.0 - U, 0.0)), W, D, P["n2"], n3)
    S0m = 0.5 * (Rs + Rp)
    Q = 0.5 * (Rs - Rp) / dr.maximum(U, _U_EPS)
    grads = []
    for var in (U, D):
        dr.forward_from(var, flags=dr.ADFlag.ClearVertices)
        grads += [dr.grad(S0m), dr.grad(Q)]
        dr.clear_grad(S0m)
        dr.clear_grad(Q)
    S0m, Q = dr.detach(S0m), dr.detach(Q)
    S0u, Qu, S0d, Qd = grads
    # one kernel for the optics and its derivatives; the band sums below then read them
    dr.eval(S0m, Q, S0u, Qu, S0d, Qd)
    r, J = _residual_parts(O[0], O[1], O[2], S0m, Q, S0u, Qu, S0d, Qd, dr.detach(P["v1"]), dr.detach(P["v2"]),
                           dr.detach(P["e1"]), dr.detach(P["e2"]), dr.detach(P["w0"]), dr.detach(P["w1"]))
    sums = [dr.block_sum(t, b) for t in _products(r, J)]
    dr.eval(*sums)
    return [s.numpy() for s in sums]


def fit_stokes_pixels(S0, S1, S2, x0, film_ior, substrate_ior, wavelengths_nm, w0=1.0, iterations=10,
                      max_step_u=0.1, max_step_nm=40.0, thickness_prior=None):
    """Levenberg-Marquardt of every pixel's ``(v1, v2, d)`` from ``x0`` (:mod:`.lm`).

    ``thickness_prior``: optional ``(d_prior, weight)`` arrays (N,): a Gaussian prior
    residual ``weight (d_prior - d)`` (in the units of the weighted data residuals) is added,
    with its cost (the data cost alone is ``aux``).

    Returns
    -------
    :class:`thinfilm.reconstruction.lm.LMResult` (``H`` is the Gauss-Newton information
    ``JᵀJ`` of the data at the solution, in the order (v1, v2, d); ``aux`` the data cost).
    """
    S0, S1, S2 = (np.asarray(a, dtype=np.float64) for a in (S0, S1, S2))
    n = S0.shape[0]
    w0 = np.broadcast_to(np.asarray(w0, dtype=np.float64), (n,))
    n2 = np.broadcast_to(np.asarray(film_ior, dtype=np.float64), (n,))

    def normal_equations(x, idx):
        H, g, cost = stokes_normal_equations(S0[idx], S1[idx], S2[idx], x, n2[idx], substrate_ior,
                                             wavelengths_nm, w0[idx])
        data = cost.copy()
        if thickness_prior is not None:
            d_p, w_p = thickness_prior[0][idx], thickness_prior[1][idx]
            H = H.copy()
            H[:, 2, 2] += w_p ** 2
            g = g.copy()
            g[:, 2] += w_p ** 2 * (x[:, 2] - d_p)
            cost = cost + (w_p * (x[:, 2] - d_p)) ** 2
        return H, g, cost, data

    def project(x):
        u = np.hypot(x[:, 0], x[:, 1])
        f = np.where(u > U_MAX, U_MAX / np.maximum(u, 1e-300), 1.0)
        x[:, 0] *= f
        x[:, 1] *= f
        x[:, 2] = np.maximum(x[:, 2], 0.0)
        return x

    return levenberg_marquardt(project(np.array(x0, dtype=np.float64)), normal_equations, iterations,
                               project=project, max_step=[max_step_u, max_step_u, max_step_nm],
                               step_tol=[1e-6, 1e-6, 1e-2], lam0=1e-3, lam_down=1.0 / 3.0, lam_up=5.0,
                               floor_rel=1e-9, floor_abs=1e-18)


def normal_information(H):
    """Information (precision, in units of the residuals' inverse variance) on each pixel's
    image-plane normal ``(a, b) = sin θ (cos φ, sin φ)`` from the fit's Gauss-Newton matrix in
    (v1, v2, d), the thickness marginalized out (``v = (a² - b², 2ab)``): its mean
    eigenvalue (N,) and the 2 x 2 matrices (N, 2, 2) of the representative with azimuth
    ``phi``."""
    Hvv = H[:, :2, :2]
    Hvd = H[:, :2, 2]
    Hdd = np.maximum(H[:, 2, 2], 1e-300)
    return Hvv - Hvd[:, :, None] * Hvd[:, None, :] / Hdd[:, None, None]


def _band_noise(spectra):
    """Robust noise of one band per spectrum: MAD of second differences / sqrt(6)."""
    d2 = spectra[:, 2:] - 2.0 * spectra[:, 1:-1] + spectra[:, :-2]
    mad = np.median(np.abs(d2 - np.median(d2, axis=1, keepdims=True)), axis=1)
    return 1.4826 * mad / np.sqrt(6.0)


def _local_median(values, mask, size):
    """Median of ``values`` over the mask pixels of each ``size`` x ``size`` window."""
    import warnings

    v = np.where(mask, values, np.nan)
    pad = size // 2
    H, W = v.shape
    win = np.lib.stride_tricks.sliding_window_view(np.pad(v, pad, constant_values=np.nan), (size, size))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(win.reshape(H, W, -1), axis=-1)
    return np.where(np.isfinite(med), med, values)


def reconstruct_stokes(stokes, wavelengths_nm, substrate_ior, mask, smoothness=2.0, surface_sigma=0.01,
                       misfit=4.0, iterations=10, thickness_sigma_nm=15.0):
    """The default spectral method on a Stokes capture (see :mod:`.spectral_default`)."""
    import time

    from scipy import ndimage

    from thinfilm.core.io import Estimate

    from . import spectral_fit as _sf
    from .azimuth import resolve_azimuth_global
    from .surface import height_to_normals, integrate_normals

    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    n3 = float(substrate_ior)
    b = wl.size
    t = {}
    t0 = time.perf_counter()
    S0, S1, S2 = (np.asarray(stokes[k], dtype=np.float64)[mask] for k in ("S0", "S1", "S2"))
    n = S0.shape[0]
    phi0, _ = axis_from_stokes(S1, S2)
    p = -(S1 * np.cos(2 * phi0)[:, None] + S2 * np.sin(2 * phi0)[:, None])   # P along the axis
    sp = np.concatenate([S0 + p, S0 - p], axis=1)                           # R_s, R_p
    noise = np.maximum(_band_noise(S0), 1e-9)
    t["prepare"] = time.perf_counter() - t0

    # 1. the film index, once for the object, on either side of the substrate's
    t0 = time.perf_counter()
    n2, n2_info = _sf.estimate_film_ior_either_side(sp, wl, n3)
    above = n2_info["film_ior_above_substrate"]
    t["film_ior"] = time.perf_counter() - t0

    # 2. every pixel's (v, d): start from its extremum (Eq. 21, 29), pixels without one from
    # the nearest pixel with one
    t0 = time.perf_counter()
    pk, th_ext = _sf.extrema_angles(sp[:, :b], wl, n3, above)
    has = np.isfinite(th_ext)
    th0 = np.zeros(n)
    d0 = np.full(n, 400.0)
    if has.any():
        th0[has] = th_ext[has]
        d0[has] = _sf.initial_thickness(sp[has], th_ext[has], pk.wavelength_nm[has], n2, n3, wl)
        img = np.full(mask.shape, -1, dtype=np.int64)
        img[mask] = np.where(has, np.arange(n), -1)
        _, (ir, ic) = ndimage.distance_transform_edt(img < 0, return_indices=True)
        src = img[ir, ic][mask]
        th0, d0 = np.where(has, th0, th0[src]), np.where(has, d0, d0[src])
    fit = fit_stokes_pixels(S0, S1, S2, angles_to_x(th0, phi0, d0), n2, n3, wl, iterations=iterations)
    x, H, cost = fit.x, fit.H, fit.cost
    # fits far above the noise started in a wrong order: restart them from their nearest
    # well-fitted pixel and from a coarse grid, keep the best
    bad = cost > misfit * 3 * b * noise ** 2
    t["fit"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if bad.any() and (~bad).any():
        img = np.full(mask.shape, -1, dtype=np.int64)
        img[mask] = np.where(~bad, np.arange(n), -1)
        _, (ir, ic) = ndimage.distance_transform_edt(img < 0, return_indices=True)
        src = img[ir, ic][mask][bad]
        starts = [x[src]]
        th_g, d_g = _sf._init_no_peak(sp[bad], n2, n3, wl, x[src, 2])
        starts.append(angles_to_x(th_g, phi0[bad], d_g))
        for x_start in starts:
            f2 = fit_stokes_pixels(S0[bad], S1[bad], S2[bad], x_start, n2, n3, wl, iterations=iterations)
            better = f2.cost < cost[bad]
            idx = np.nonzero(bad)[0][better]
            x[idx], H[idx], cost[idx] = f2.x[better], f2.H[better], f2.cost[better]
    # thickness varies smoothly over a film: where the spectrum leaves the order open (weak
    # fringes, an index close to the substrate's), a pixel takes the one nearest the local
    # median of its neighbours (a Gaussian prior, thickness_sigma_nm); pixels far from it
    # start from it
    d_img = np.full(mask.shape, np.nan)
    d_img[mask] = x[:, 2]
    d_med = _local_median(d_img, mask, 7)[mask]
    far = np.abs(x[:, 2] - d_med) > 2.0 * thickness_sigma_nm
    x_start = x.copy()
    x_start[far, 2] = d_med[far]
    prior = (d_med, noise / thickness_sigma_nm)
    f3 = fit_stokes_pixels(S0, S1, S2, x_start, n2, n3, wl, iterations=iterations, thickness_prior=prior)
    x, H, cost = f3.x, f3.H, f3.aux
    t["refit"] = time.perf_counter() - t0

    # 3. one surface: the azimuth's sign for the whole object, then the normals integrated to
    # a height field (weighted by their information) and each pixel's normal fused with it
    t0 = time.perf_counter()
    theta, phi, d = x_to_angles(x)
    Iv = normal_information(H) / noise[:, None, None] ** 2
    a, bb = np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi)
    Jn = 2.0 * np.stack([np.stack([a, -bb], -1), np.stack([bb, a], -1)], axis=-2)
    In = np.einsum("nki,nkl,nlj->nij", Jn, Iv, Jn)
    w_n = 0.5 * np.trace(In, axis1=1, axis2=2)
    zen = np.full(mask.shape, np.nan)
    azm = np.full(mask.shape, np.nan)
    zen[mask], azm[mask] = np.degrees(theta), np.degrees(phi)
    w_img = np.zeros(mask.shape)
    w_img[mask] = w_n
    # confidence in the azimuth's axis: 1 where its standard deviation is below 0.05 rad
    conf = np.clip(w_img * np.sin(np.radians(np.nan_to_num(zen))) ** 2 * 0.05 ** 2, 0.0, 1.0)
    az = resolve_azimuth_global(azm, zen, mask, conf)
    t["azimuth"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    from thinfilm.core.conventions import angles_to_normals

    normals = angles_to_normals(zen, np.nan_to_num(az))
    nz = np.clip(normals[..., 2], 0.0, 1.0)
    weights = np.where(mask, w_img * nz ** 4, 0.0)
    weights = weights / max(np.mean(weights[mask]), 1e-300)
    height = integrate_normals(normals, mask, weights, smoothness=smoothness)
    n_surf = height_to_normals(height, mask)
    # fuse: Gaussian data term (information In) and the surface's normal (σ = surface_sigma)
    ns = n_surf[mask][:, :2]
    sgn = np.where(np.cos(np.radians(az[mask]) - phi) >= 0, 1.0, -1.0)
    nd = sgn[:, None] * np.stack([a, bb], -1)
    A = In + np.eye(2)[None] / surface_sigma ** 2
    rhs = np.einsum("nij,nj->ni", In, nd) + ns / surface_sigma ** 2
    nxy = np.linalg.solve(A, rhs[..., None])[..., 0]
    r = np.linalg.norm(nxy, axis=1)
    nxy = np.where(r[:, None] > 0.9999, nxy / np.maximum(r, 1e-12)[:, None] * 0.9999, nxy)
    out_n = np.zeros(mask.shape + (3,))
    out_n[mask] = np.concatenate([nxy, np.sqrt(1.0 - np.sum(nxy ** 2, axis=1))[:, None]], axis=1)
    t["surface"] = time.perf_counter() - t0

    # 4. thickness at the final normal: the fit's linear coupling of d to v
    t0 = time.perf_counter()
    th_f = np.arcsin(np.clip(np.linalg.norm(nxy, axis=1), 0.0, 1.0))
    ph_f = np.arctan2(nxy[:, 1], nxy[:, 0])
    dv = angles_to_x(th_f, ph_f, d)[:, :2] - x[:, :2]
    shift = -np.einsum("ni,ni->n", H[:, 2, :2], dv) / np.maximum(H[:, 2, 2], 1e-300)
    d_f = np.maximum(d + np.clip(shift, -20.0, 20.0), 0.0)
    t["thickness"] = time.perf_counter() - t0
    thickness = np.full(mask.shape, np.nan)
    thickness[mask] = d_f
    valid = mask & np.isfinite(thickness)
    info = {"timings_s": t, **n2_info, "capture": "stokes", "refit_poor": int(bad.sum()),
            "smoothness": smoothness}
    return Estimate(normals=out_n, thickness_nm=thickness, valid=valid, film_ior=float(n2),
                    substrate_ior=n3, height=height, info=info)
