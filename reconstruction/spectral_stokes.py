"""Per-pixel fits of the linear Stokes cube of a rotating-polarizer hyperspectral capture.

A specular pixel of zenith θ and azimuth φ (orthographic camera) reflects the unpolarized
dome as ``S0 = (R_s + R_p)/2``, ``(S1, S2) = -P (cos 2φ, sin 2φ)`` with ``P = (R_s - R_p)/2``
(:func:`thinfilm.core.conventions.specular_stokes`) at every band. The unknowns of a pixel are
carried as ``x = (v1, v2, d)`` with ``(v1, v2) = u (cos 2φ, sin 2φ)`` and ``u = sin² θ``: then
``(S1, S2) = -Q(u, d) (v1, v2)`` with ``Q = P / u``, smooth through normal incidence, where φ
is undefined (the observation model's ``double_angle`` parametrization,
:data:`thinfilm.core.model.PARAMETRIZATIONS`). The angle of polarization fixes φ modulo
180°, and the s and p spectra together fix θ at every pixel: with the film index known, each
pixel's zenith, azimuth axis and thickness come from one least-squares fit to all 3 B values.

The model and its Gauss-Newton normal equations are the observation model's
(:meth:`thinfilm.core.model.ObservationModel.normal_equations`: one kernel over pixels,
looping over the bands, the Jacobian by forward-mode AD); :func:`fit_stokes_pixels` runs the
batched Levenberg-Marquardt of :mod:`.lm` on it.

The noise of the Stokes fit of a four-angle rotating polarizer (0, 45, 90, 135°) is
``σ(S1) = σ(S2) = √2 σ(S0)``; the residuals are weighted accordingly (``w1 = w0 / √2``).
"""

from __future__ import annotations

import numpy as np

from thinfilm.core.errors import UserError
from thinfilm.core.model import Observations

from .lm import levenberg_marquardt
from .peaks import band_noise
from .spectral_model import model_for

__all__ = ["U_MAX", "stokes_model", "StokesData", "stokes_normal_equations", "fit_stokes_pixels",
           "axis_from_stokes", "x_to_angles", "angles_to_x", "normal_information", "reconstruct_stokes"]

#: largest ``u = sin² θ`` a fit may reach (θ = 89.5°)
U_MAX = float(np.sin(np.radians(89.5)) ** 2)
_N2_REF = 1.0


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
    """``S0`` and ``Q = P / u`` (N, B) of pixels with ``u = sin² θ`` and thickness (N,), by the
    observation model (``wavelengths_nm``: band centres or a :class:`~thinfilm.core.model.Rig`)."""
    u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
    d = np.asarray(thickness_nm, dtype=np.float64)
    n2 = np.broadcast_to(np.asarray(film_ior, dtype=np.float64), u.shape)
    model = model_for(wavelengths_nm, substrate_ior, d, n2)
    b = len(model.rig.wavelengths_nm)
    # azimuth 90°: (v1, v2) = (-u, 0), so S1 = -Q v1 = Q u
    x = np.stack([-u, np.zeros_like(u), d, n2 - _N2_REF], axis=1)
    s = model.evaluate("stokes", x, "double_angle")
    return s[:, :b], s[:, b:2 * b] / np.maximum(u, 1e-9)[:, None]


class StokesData:
    """Measured Stokes spectra of N pixels, with their residual weights, ready for repeated
    evaluations of the normal equations (uploaded to the model's kernels once).

    Parameters
    ----------
    S0, S1, S2 : (N, B) measured Stokes spectra.
    wavelengths_nm : (B,) band centres, or the dataset's :class:`~thinfilm.core.model.Rig`.
    w0, w1 : float or (N,) residual weights (``w1`` defaults to ``w0 / √2``).
    """

    def __init__(self, S0, S1, S2, wavelengths_nm, w0=1.0, w1=None):
        S = [np.ascontiguousarray(a, dtype=np.float64) for a in (S0, S1, S2)]
        n, b = S[0].shape
        self.n, self.b = n, b
        self.wavelengths_nm = wavelengths_nm
        self.w0 = np.broadcast_to(np.asarray(w0, dtype=np.float64), (n,)).copy()
        self.w1 = self.w0 / np.sqrt(2.0) if w1 is None else np.broadcast_to(np.asarray(w1, dtype=np.float64), (n,)).copy()
        self.observations = Observations("stokes", S, (self.w0, self.w1))

    def normal_equations(self, x, idx, film_ior, substrate_ior, model=None):
        """Gauss-Newton normal equations at ``x`` (n, 3) of the pixels ``idx`` (n,).

        Residuals per band: ``w0 (S0 - S0(u, d))``, ``w1 (S1 - S1(v, d))``, ``w1 (S2 - S2(v, d))``.
        ``model``: the observation model to use (default: chosen for the thicknesses of ``x``).

        Returns
        -------
        H : (n, 3, 3) ``JᵀJ``; g : (n, 3) ``Jᵀr`` (J the Jacobian of the residuals); cost :
        (n,) ``Σ r²``.
        """
        x = np.asarray(x, dtype=np.float64)
        idx = np.asarray(idx)
        n2 = np.broadcast_to(np.asarray(film_ior, dtype=np.float64), (idx.size,))
        if model is None:
            model = model_for(self.wavelengths_nm, substrate_ior, x[:, 2], n2)
        return model.normal_equations(self.observations, x, "double_angle",
                                      {"index_offset.0": n2 - _N2_REF}, rows=idx)


def stokes_normal_equations(S0, S1, S2, x, film_ior, substrate_ior, wavelengths_nm, w0=1.0, w1=None):
    """Gauss-Newton normal equations of the Stokes model at ``x`` (N, 3) for N pixels
    (:meth:`StokesData.normal_equations` of all of them)."""
    data = StokesData(S0, S1, S2, wavelengths_nm, w0, w1)
    return data.normal_equations(x, np.arange(data.n), film_ior, substrate_ior)


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
    data = S0 if isinstance(S0, StokesData) else StokesData(S0, S1, S2, wavelengths_nm, w0)
    n = data.n
    n2 = np.broadcast_to(np.asarray(film_ior, dtype=np.float64), (n,))
    x0 = np.array(x0, dtype=np.float64)
    # one quadrature for the whole fit: that of the thickest start, with room for its steps
    model = model_for(data.wavelengths_nm, substrate_ior, x0[:, 2] + max_step_nm, n2)

    def normal_equations(x, idx):
        H, g, cost = data.normal_equations(x, idx, n2[idx], substrate_ior, model)
        data_cost = cost.copy()
        if thickness_prior is not None:
            d_p, w_p = thickness_prior[0][idx], thickness_prior[1][idx]
            H[:, 2, 2] += w_p ** 2
            g[:, 2] += w_p ** 2 * (x[:, 2] - d_p)
            cost = cost + (w_p * (x[:, 2] - d_p)) ** 2
        return H, g, cost, data_cost

    def project(x):
        u = np.hypot(x[:, 0], x[:, 1])
        f = np.where(u > U_MAX, U_MAX / np.maximum(u, 1e-300), 1.0)
        x[:, 0] *= f
        x[:, 1] *= f
        x[:, 2] = np.maximum(x[:, 2], 0.0)
        return x

    return levenberg_marquardt(project(x0), normal_equations, iterations,
                               project=project, max_step=[max_step_u, max_step_u, max_step_nm],
                               step_tol=[3e-5, 3e-5, 0.1], lam0=1e-3, lam_down=1.0 / 3.0, lam_up=5.0,
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


def _nearest(mask, which):
    """For every mask pixel (in mask order), the index (in mask order) of the nearest mask
    pixel where ``which`` holds."""
    from scipy import ndimage

    img = np.full(mask.shape, -1, dtype=np.int64)
    img[mask] = np.where(which, np.arange(which.size), -1)
    _, (ir, ic) = ndimage.distance_transform_edt(img < 0, return_indices=True)
    return img[ir, ic][mask]


def _interpolate_seeds(mask, seeds, *values, radius=2.0):
    """Per mask pixel, the Gaussian-weighted mean (σ = ``radius`` px) of each of ``values``
    over the seeds within reach, where the seeds' values agree; the nearest seed's value
    elsewhere (a pixel between seeds of two surfaces, or far from any seed)."""
    from scipy import ndimage

    w = np.zeros(mask.shape)
    w[mask] = seeds
    den = ndimage.gaussian_filter(w, radius, truncate=2.0)
    src = _nearest(mask, seeds)
    out = []
    for v in values:
        img = np.zeros(mask.shape)
        img[mask] = np.where(seeds, v, 0.0)
        mean = ndimage.gaussian_filter(img, radius, truncate=2.0)[mask] / np.maximum(den[mask], 1e-12)
        sq = np.zeros(mask.shape)
        sq[mask] = np.where(seeds, v * v, 0.0)
        var = ndimage.gaussian_filter(sq, radius, truncate=2.0)[mask] / np.maximum(den[mask], 1e-12) - mean ** 2
        near = v[src]
        # the seeds around a pixel disagree (an edge, another order): the nearest one
        spread = np.sqrt(np.maximum(var, 0.0))
        agree = (den[mask] > 1e-3) & (spread < 0.05 * np.maximum(np.abs(mean), 1e-9) + 1e-9)
        out.append(np.where(agree, mean, near))
    return out


def reconstruct_stokes(stokes, wavelengths_nm, substrate_ior, mask, smoothness=2.0, surface_sigma=0.01,
                       misfit=4.0, iterations=8, thickness_sigma_nm=15.0, seed_step=3, max_chi2=10.0,
                       thickness_range_nm=None, band_fwhm_nm=0.0):
    """The Stokes method: each pixel's s and p spectra fitted, one surface (the stages are
    described in the body; the model in the module docstring).

    ``thickness_range_nm``: the film thicknesses considered (default
    :data:`thinfilm.core.bands.SPECTRAL_THICKNESS_RANGE_NM`, less where the bands of width
    ``band_fwhm_nm`` cannot resolve the fringes: then one warning says so).
    """
    import time

    from thinfilm.core.io import Estimate

    from . import spectral_fit as _sf
    from .azimuth import resolve_azimuth_global
    from .masks import masked_median
    from .surface import height_to_normals, integrate_normals

    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    n3 = float(substrate_ior)
    limits = _sf.thickness_limits(wl, thickness_range_nm, band_fwhm_nm)
    b = wl.size
    t = {}
    t0 = time.perf_counter()
    S0, S1, S2 = (np.asarray(np.asarray(stokes[k])[mask], dtype=np.float64) for k in ("S0", "S1", "S2"))
    n = S0.shape[0]
    phi0, _ = axis_from_stokes(S1, S2)

    def sp_of(rows):
        """R_s and R_p spectra (s then p) of some pixels: S0 ± P along the azimuth's axis."""
        c, s_ = np.cos(2 * phi0[rows])[:, None], np.sin(2 * phi0[rows])[:, None]
        p_ = -(S1[rows] * c + S2[rows] * s_)
        return np.concatenate([S0[rows] + p_, S0[rows] - p_], axis=1)

    noise = np.maximum(band_noise(S0), 1e-9)
    t["prepare"] = time.perf_counter() - t0

    # 1. the film index, once for the object, on either side of the substrate's (from an even
    # sample of the pixels)
    t0 = time.perf_counter()
    sample = np.unique(np.linspace(0, n - 1, min(n, 4000)).round().astype(np.int64))
    n2, n2_info = _sf.estimate_film_ior_either_side(sp_of(sample), wl, n3, limits=limits)
    limits.warn_if_cut(n2)
    above = n2_info["film_ior_above_substrate"]
    t["film_ior"] = time.perf_counter() - t0

    # 2. every pixel's (v, d). Seeds on a sparse grid start from their extremum (Eq. 21) and
    # the best order of interference (Eq. 29) and are fitted first; every other pixel starts
    # from its nearest fitted seed (surface and film are continuous), with its own azimuth
    t0 = time.perf_counter()
    rows, cols = np.nonzero(mask)
    grid = (rows % seed_step == 0) & (cols % seed_step == 0)
    if grid.sum() < 50:
        grid = np.ones(n, dtype=bool)
    gi = np.nonzero(grid)[0]
    sp_g = sp_of(gi)
    pk, th_ext = _sf.extrema_angles(sp_g[:, :b], wl, n3, above)
    ok = np.isfinite(th_ext)
    if not ok.any():
        gi = np.arange(n)
        sp_g = sp_of(gi)
        pk, th_ext = _sf.extrema_angles(sp_g[:, :b], wl, n3, above)
        ok = np.isfinite(th_ext)
    if not ok.any():
        raise UserError("stokes_spectral: no pixel shows the interference extremum the index "
                        f"{n2:.3f} implies, so no pixel's angle can be started")
    seeds = gi[ok]
    d_s = _sf.initial_thickness(sp_g[ok], th_ext[ok], pk.wavelength_nm[ok], n2, n3, wl, limits=limits)
    t["init"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    fs = fit_stokes_pixels(S0[seeds], S1[seeds], S2[seeds], angles_to_x(th_ext[ok], phi0[seeds], d_s), n2, n3, wl,
                           iterations=iterations)
    is_seed = np.zeros(n, dtype=bool)
    is_seed[seeds] = True
    # seeds that did not fit (a wrong extremum or order) seed nobody
    good_seed = np.zeros(n, dtype=bool)
    good_seed[seeds] = fs.cost < misfit * 3 * b * noise[seeds] ** 2
    if not good_seed.any():
        good_seed[seeds] = True
    x = np.zeros((n, 3))
    x[seeds] = fs.x
    th_s, _, d_s2 = x_to_angles(x)
    th_i, d_i = _interpolate_seeds(mask, good_seed, th_s, d_s2)
    x0 = angles_to_x(th_i, phi0, d_i)
    rest = np.nonzero(~is_seed)[0]
    fit = fit_stokes_pixels(S0[rest], S1[rest], S2[rest], x0[rest], n2, n3, wl, iterations=iterations)
    H = np.zeros((n, 3, 3))
    cost = np.zeros(n)
    x[rest], H[rest], cost[rest] = fit.x, fit.H, fit.cost
    H[seeds], cost[seeds] = fs.H, fs.cost
    t["fit"] = time.perf_counter() - t0
    # fits far above the noise started in a wrong order: restart them from their nearest
    # well-fitted pixel and from a coarse grid, keep the best
    t0 = time.perf_counter()
    bad = cost > misfit * 3 * b * noise ** 2
    if bad.any() and (~bad).any():
        src = _nearest(mask, ~bad)[bad]
        starts = [x[src]]
        th_g, d_g = _sf.init_no_peak(sp_of(np.nonzero(bad)[0]), n2, n3, wl, x[src, 2])
        starts.append(angles_to_x(th_g, phi0[bad], d_g))
        for x_start in starts:
            f2 = fit_stokes_pixels(S0[bad], S1[bad], S2[bad], x_start, n2, n3, wl, iterations=iterations)
            better = f2.cost < cost[bad]
            idx = np.nonzero(bad)[0][better]
            x[idx], H[idx], cost[idx] = f2.x[better], f2.H[better], f2.cost[better]
    # thickness varies smoothly over a film: where the spectrum leaves the order open (weak
    # fringes, an index close to the substrate's), a pixel takes the order nearest the
    # local median of its neighbours (a Gaussian prior of thickness_sigma_nm); pixels far
    # from it start from it. Pixels whose own data fix the thickness much better than the
    # prior and that agree with their neighbours are left as they are.
    d_img = np.full(mask.shape, np.nan)
    d_img[mask] = x[:, 2]
    d_med = masked_median(d_img, mask, 7)[mask]
    far = np.abs(x[:, 2] - d_med) > 2.0 * thickness_sigma_nm
    info_d = H[:, 2, 2] - np.einsum("ni,nij,nj->n", H[:, 2, :2], np.linalg.pinv(H[:, :2, :2]), H[:, :2, 2])
    weak = info_d < 25.0 * (noise / thickness_sigma_nm) ** 2
    redo = far | weak | (np.abs(x[:, 2] - d_med) > 0.5 * thickness_sigma_nm)
    if redo.any():
        x_start = x[redo].copy()
        x_start[far[redo], 2] = d_med[redo][far[redo]]
        prior = (d_med[redo], noise[redo] / thickness_sigma_nm)
        f3 = fit_stokes_pixels(S0[redo], S1[redo], S2[redo], x_start, n2, n3, wl, iterations=iterations,
                               thickness_prior=prior)
        x[redo], H[redo], cost[redo] = f3.x, f3.H, f3.aux
    t["prior_refit"] = int(redo.sum())
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
    az, az_info = resolve_azimuth_global(azm, zen, mask, conf, return_info=True)
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
    chi2 = cost / (3 * b * noise ** 2)
    # 5. uncertainty: the fused normal's covariance (data and surface), inflated by the fit's
    # reduced chi2 where the data fit worse than the noise; the thickness's conditional
    # variance at fixed normal plus what the final normal's uncertainty carries through the
    # fit's d-v coupling
    inflate = np.maximum(1.0, chi2)
    C_ab = np.linalg.inv(In / inflate[:, None, None] + np.eye(2)[None] / surface_sigma ** 2)
    from thinfilm.core.bound import angle_sigma_deg, image_plane_jacobian

    sig_n = np.full(mask.shape, np.nan)
    sig_n[mask] = angle_sigma_deg(image_plane_jacobian(nxy), C_ab)
    a_f, b_f = nxy[:, 0], nxy[:, 1]
    Jv = 2.0 * np.stack([np.stack([a_f, -b_f], -1), np.stack([b_f, a_f], -1)], axis=-2)   # dv/d(a, b)
    C_v = np.einsum("nik,nkl,njl->nij", Jv, C_ab, Jv)
    g = -H[:, 2, :2] / np.maximum(H[:, 2, 2], 1e-300)[:, None]
    var_d = (inflate * noise ** 2 / np.maximum(H[:, 2, 2], 1e-300) + np.einsum("ni,nij,nj->n", g, C_v, g)
             + _sf.index_thickness_sigma(d_f, th_f, n2) ** 2)
    sig_d = np.full(mask.shape, np.nan)
    sig_d[mask] = np.sqrt(var_d)
    # pixels the model cannot explain (an inter-reflection in a concave part, a rim the
    # light grazes) are reported invalid
    explained = np.zeros(mask.shape, dtype=bool)
    explained[mask] = chi2 < max_chi2
    valid = mask & np.isfinite(thickness) & explained
    info = {"timings_s": t, **n2_info, "capture": "stokes", "refit_poor": int(bad.sum()),
            "azimuth_sign_by_prior": az_info["sign_by_prior"],
            "unexplained_pixels": int(np.sum(chi2 >= max_chi2)),
            "smoothness": smoothness, "thickness_range_nm": [limits.lo, limits.upper(n2)]}
    unexplained = int(np.sum(chi2 >= max_chi2))
    if not valid.any():
        # said by the command line instead of an estimate with no valid pixel
        info["no_result_reason"] = (f"one film of a constant index ({n2:.3f}) explains none of the {n} pixels' "
                                    f"spectra: reduced chi2 >= {max_chi2:g} everywhere")
    elif unexplained > n // 2:
        import warnings

        from thinfilm.core.errors import ThinfilmWarning

        warnings.warn(f"stokes_spectral: one film of a constant index ({n2:.3f}) explains only {n - unexplained} "
                      f"of the {n} pixels' spectra (reduced chi2 >= {max_chi2:g} elsewhere, those pixels are "
                      f"invalid): the film may not be of one constant index", ThinfilmWarning, stacklevel=2)
    return Estimate(normals=out_n, thickness_nm=thickness, valid=valid, film_ior=float(n2),
                    substrate_ior=n3, height=height, info=info, normal_sigma_deg=sig_n, thickness_sigma_nm=sig_d)
