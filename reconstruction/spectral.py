"""Reconstruction from s-polarized hyperspectral images, film index unknown (paper Sec. 6).

Input: ``spectral_s`` (H, W, B), the s reflectance per band, and the substrate index ``n3``.
Output: normals, film thickness per pixel and one film index ``n2`` for the object.

Methods (``method=`` name → function, see :data:`METHODS`):

``"kobayashi"`` (aliases ``"published"``, ``"paper"``) — the paper as published:
    1. peak (constructive interference, ``e^{iΔ} = 1``) per pixel; the incident angle from the
       peak reflectance by inverting Eq. 21 (monotone in θ);
    2. normals by Horn's characteristic strip expansion (Sec. 6.2,
       :func:`thinfilm.reconstruction.eikonal.characteristic_strips`);
    3. ``n2`` and ``d`` per pixel by the integer-order search of Eqs. 28–30: ``n2`` from 1.00 to
       ``n3`` in steps of 0.01, every order ``m`` with ``d = m λ_peak / (2 sqrt(n2² - sin² θ))``
       below 1000 nm, least squares over the whole spectrum; the object's ``n2`` is the median.
    Pixels without a peak in the measured range get no angle and stay invalid.

``"eikonal"`` (the default; alias ``"default"``) — the same physics, solved at the object level:
    1. peaks as above give a first angle where they exist;
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

The substrate must be a dielectric (``k3 = 0``): the capture ``S0 + sqrt(S1² + S2²)`` is
``max(R_s, R_p)``, which is ``R_s`` for a film on a dielectric but not on an absorbing substrate,
so datasets with ``substrate_k > 0`` are refused. Heights (``surface.ply``) are in scene units
when the dataset's ``meta.json`` gives ``projection.pixel_size``, else in pixels.

The film must be optically thinner than the substrate (``n2 < n3``); otherwise the
constructive-interference extremum is a minimum and the method does not apply. Spectra that
never dip below the bare substrate's normal-incidence reflectance are reported as such.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from thinfilm.errors import UserError

from . import eikonal as _eik
from . import spectral_model as _sm
from .masks import mask_from_intensity, read_mask_file
from .peaks import PEAK_NONE, PEAK_OK, PEAK_SEVERAL, find_peaks

__all__ = [
    "METHODS",
    "ALIASES",
    "DEFAULT_METHOD",
    "PAPER_METHOD",
    "MIN_BANDS",
    "SpectralEstimate",
    "reconstruct_spectral",
    "reconstruct_kobayashi",
    "reconstruct_eikonal",
    "object_mask",
    "check_peak_assumption",
    "kobayashi_search",
    "estimate_film_ior",
    "fit_angle_thickness",
    "initial_thickness",
    "cli_main",
]

MIN_BANDS = 10
MAX_THICKNESS_NM = 1000.0


@dataclass
class SpectralEstimate:
    """Result of a spectral reconstruction.

    Attributes
    ----------
    normals : (H, W, 3) unit normals (camera frame).
    thickness_nm : (H, W) film thickness.
    valid : (H, W) bool.
    film_ior : float, the estimated film index n2.
    incident_deg : (H, W) incident angle per pixel (final).
    height : (H, W) height in the unit of ``pixel_size`` (pixels by default) or None.
    info : dict of diagnostics for ``estimate.json`` (peak statistics, timings …).
    """

    normals: np.ndarray
    thickness_nm: np.ndarray
    valid: np.ndarray
    film_ior: float
    incident_deg: np.ndarray
    height: np.ndarray | None = None
    info: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------
# Input checks and masks
# ---------------------------------------------------------------------------


def _check_cube(cube, wavelengths_nm, where="spectral_s"):
    cube = np.asarray(cube, dtype=np.float64)
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    if cube.ndim != 3:
        raise UserError(f"{where}: expected an (H, W, bands) cube, got shape {cube.shape}")
    if wl.ndim != 1 or wl.size != cube.shape[2]:
        raise UserError(f"{where}: {cube.shape[2]} bands but {wl.size} wavelengths in 'wavelengths_nm'")
    if wl.size < MIN_BANDS:
        raise UserError(f"{where}: only {wl.size} spectral bands, the spectral method needs at least {MIN_BANDS}")
    if np.any(np.diff(wl) <= 0):
        raise UserError(f"{where}: 'wavelengths_nm' must be strictly increasing")
    if not np.all(np.isfinite(cube)):
        raise UserError(f"{where}: spectra contain NaN or infinite values")
    return cube, wl


def object_mask(cube):
    """Object pixels of a spectral cube against its dark background: the project's intensity
    mask (:func:`thinfilm.reconstruction.masks.mask_from_intensity`) of the band mean."""
    return mask_from_intensity(np.asarray(cube).mean(axis=2))


def check_peak_assumption(spectra, substrate_ior, noise=None):
    """Raise :class:`UserError` when the spectra say ``n2 >= n3`` (peaks are minima).

    With ``n2 < n3`` a film's reflectance dips below the bare substrate's (the quarter-wave
    troughs; at small angles below the substrate's normal-incidence value ``R0``). With
    ``n2 > n3`` it never does: every extremum at ``e^{iΔ} = 1`` is a *minimum* equal to the
    substrate's, and Eq. 21 would read minima as peaks. The test: among pixels whose spectra
    oscillate clearly, almost none dips below ``R0``.

    Parameters
    ----------
    spectra : (N, B) object spectra.
    substrate_ior : float.
    noise : (N,) per-band noise, optional.
    """
    S = np.asarray(spectra, dtype=np.float64)
    if S.shape[0] < 20:
        return
    r0 = float(_sm.peak_reflectance(0.0, substrate_ior))
    lo = ndimage.gaussian_filter1d(S, 1.5, axis=1).min(axis=1)
    hi = ndimage.gaussian_filter1d(S, 1.5, axis=1).max(axis=1)
    nz = np.zeros(S.shape[0]) if noise is None else np.asarray(noise)
    oscillating = (hi - lo) > np.maximum(0.15 * hi, 6.0 * nz)
    if oscillating.sum() < 20:
        return
    dips = lo[oscillating] < r0 * 0.97
    if dips.mean() < 0.02:
        raise UserError(
            f"spectral_s: the spectra never dip below the bare substrate's reflectance "
            f"({r0:.4f} for substrate index {substrate_ior:g}), so the film index is not below the "
            f"substrate's and the constructive-interference peaks are minima; the spectral method "
            f"needs n2 < n3 (check --substrate-ior)")


# ---------------------------------------------------------------------------
# The paper's (n2, m) search, Eqs. 28-30
# ---------------------------------------------------------------------------


def _film_ior_grid(substrate_ior):
    # 1.00, 1.01, ... up to (not including) n3
    k = int(np.floor((substrate_ior - 1.0) / 0.01 + 1e-9))
    g = np.round(1.0 + 0.01 * np.arange(k + 1), 2)
    return g[g < substrate_ior - 1e-9]


def _order_candidates(theta, peak_wl, n2_values, max_thickness_nm=MAX_THICKNESS_NM):
    """Eq. 29 thickness candidates ``d = m λ / (2 sqrt(n2² - sin² θ))`` for every n2 and m >= 1
    with ``d < max_thickness_nm``: (N, K) thickness and film index, NaN-padded."""
    s2 = np.sin(theta) ** 2
    n2 = np.asarray(n2_values, dtype=np.float64)
    q2 = np.sqrt(np.maximum(n2[None, :] ** 2 - s2[:, None], 1e-12))  # (N, G)
    unit = peak_wl[:, None] / (2.0 * q2)  # d for m = 1
    with np.errstate(invalid="ignore"):
        m_max = np.nan_to_num(np.ceil(max_thickness_nm / unit) - 1, nan=0).astype(int)
    M = max(1, int(np.max(m_max, initial=1)))
    m = np.arange(1, M + 1)
    d = unit[:, :, None] * m[None, None, :]  # (N, G, M)
    d = np.where(m[None, None, :] <= m_max[:, :, None], d, np.nan)
    n2b = np.broadcast_to(n2[None, :, None], d.shape)
    return d.reshape(d.shape[0], -1), n2b.reshape(d.shape[0], -1), m


def kobayashi_search(spectra, theta_rad, peak_wl_nm, substrate_ior, wavelengths_nm,
                     max_thickness_nm=MAX_THICKNESS_NM):
    """The paper's per-pixel search (Eqs. 28–30) over ``n2`` ∈ {1.00, 1.01, …} < n3 and orders m.

    Returns
    -------
    film_ior, thickness_nm, sse : (N,) arrays (NaN where the pixel has no peak).
    """
    S = np.asarray(spectra, dtype=np.float64)
    th = np.asarray(theta_rad, dtype=np.float64)
    lam = np.asarray(peak_wl_nm, dtype=np.float64)
    n = S.shape[0]
    out_n2 = np.full(n, np.nan)
    out_d = np.full(n, np.nan)
    out_e = np.full(n, np.nan)
    ok = np.isfinite(th) & np.isfinite(lam)
    if not ok.any():
        return out_n2, out_d, out_e
    grid = _film_ior_grid(substrate_ior)
    d, n2, _ = _order_candidates(th[ok], lam[ok], grid, max_thickness_nm)
    sse = _sm.grid_sse(S[ok], th[ok], d, n2, substrate_ior, wavelengths_nm)
    best = np.argmin(sse, axis=1)
    rows = np.arange(best.size)
    out_n2[ok] = n2[rows, best]
    out_d[ok] = d[rows, best]
    out_e[ok] = sse[rows, best]
    return out_n2, out_d, out_e


# ---------------------------------------------------------------------------
# Continuous fits through the optics core
# ---------------------------------------------------------------------------


def fit_angle_thickness(spectra, theta0, thickness0, film_ior, substrate_ior, wavelengths_nm,
                        iterations=12, fit_theta=True, theta_max_deg=89.5, stokes_noise=None):
    """Levenberg-Marquardt per pixel of (θ, d) — or d alone — to the whole spectrum.

    Parameters
    ----------
    spectra : (N, B) measured s reflectance.
    theta0, thickness0 : (N,) starting values (radians, nm).
    film_ior, substrate_ior : float.
    fit_theta : bool
        False: θ stays at ``theta0`` and only the thickness is fitted.
    stokes_noise : (N,) array_like, optional
        Per-pixel noise of the measured S1, S2: the model then includes the noise bias of
        ``S0 + sqrt(S1² + S2²)`` (see :func:`thinfilm.reconstruction.spectral_model.rs_spectra`).

    Returns
    -------
    theta, thickness, sse, sigma_theta : (N,) arrays; ``sigma_theta`` is the standard deviation
    of θ from the Gauss-Newton covariance with the residual variance of the pixel (inf where the
    spectrum does not constrain θ).
    """
    S = np.asarray(spectra, dtype=np.float64)
    th, d, cur = _levenberg_marquardt(S, theta0, thickness0, film_ior, substrate_ior, wavelengths_nm,
                                      iterations, fit_theta, theta_max_deg, stokes_noise)
    return th, d, cur[:, 5], _sigma_theta(cur, S.shape[1], fit_theta)


def _sigma_theta(cur, bands, fit_theta=True):
    """Standard deviation of θ from the normal equations ``cur`` ([a11 a12 a22 g1 g2 sse])."""
    n = cur.shape[0]
    if not fit_theta:
        return np.full(n, np.inf)
    var = cur[:, 5] / max(bands - 2, 1)
    det = cur[:, 0] * cur[:, 2] - cur[:, 1] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        cov_tt = np.where(det > 0, cur[:, 2] / det, np.inf)
        sigma = np.sqrt(var * cov_tt)
    return np.where(np.isfinite(sigma), sigma, np.inf)


def _levenberg_marquardt(S, theta0, thickness0, film_ior, substrate_ior, wavelengths_nm,
                         iterations=12, fit_theta=True, theta_max_deg=89.5, stokes_noise=None):
    """The iterations of :func:`fit_angle_thickness`: final (θ, d) and, per pixel, the normal
    equations at that point, ``[a11 a12 a22 g1 g2 sse]`` (θ first, then d)."""
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    th = np.array(theta0, dtype=np.float64)
    d = np.array(thickness0, dtype=np.float64)
    n = S.shape[0]
    lam = np.full(n, 1e-3)
    th_max = np.radians(theta_max_deg)
    noise = None if stokes_noise is None else np.broadcast_to(np.asarray(stokes_noise, float), (n,))

    jac = ("theta", "thickness") if fit_theta else ("thickness",)

    def evaluate(idx, th_, d_):
        nz = None if noise is None else noise[idx]
        out = _sm.rs_spectra(th_, d_, film_ior, substrate_ior, wl, jac=jac, stokes_noise=nz)
        r = S[idx] - out[0]
        Jt = out[1] if fit_theta else np.zeros_like(r)
        Jd = out[-1]
        dot = lambda x, y: np.einsum("ij,ij->i", x, y)  # noqa: E731
        # normal equations and gradient per pixel: [a11 a12 a22 g1 g2 sse]
        return np.stack([dot(Jt, Jt), dot(Jt, Jd), dot(Jd, Jd), dot(Jt, r), dot(Jd, r), dot(r, r)], -1)

    # Levenberg-Marquardt; each iteration evaluates the model and its Jacobian once, at the
    # trial point (kept when the residual drops, else the damping grows), for the pixels that
    # are still moving
    cur = np.empty((n, 6))
    cur[:] = evaluate(np.arange(n), th, d)
    active = np.ones(n, dtype=bool)
    for _ in range(iterations):
        idx = np.nonzero(active)[0]
        if idx.size == 0:
            break
        a11, a12, a22, g1, g2, e0 = cur[idx].T
        l = lam[idx]
        if fit_theta:
            b11, b22 = a11 * (1 + l) + 1e-18, a22 * (1 + l) + 1e-18
            det = b11 * b22 - a12 * a12
            dt = (b22 * g1 - a12 * g2) / det
            dd = (b11 * g2 - a12 * g1) / det
        else:
            dd = g2 / (a22 * (1 + l) + 1e-18)
            dt = np.zeros_like(dd)
        # steps of d within a quarter period at the shortest wavelength (no order jumps)
        dd = np.clip(dd, -40.0, 40.0)
        dt = np.clip(dt, -0.2, 0.2)
        th_new = np.clip(np.abs(th[idx] + dt), 0.0, th_max)
        d_new = np.maximum(d[idx] + dd, 0.0)
        new = evaluate(idx, th_new, d_new)
        better = new[:, 5] < e0
        th[idx] = np.where(better, th_new, th[idx])
        d[idx] = np.where(better, d_new, d[idx])
        cur[idx] = np.where(better[:, None], new, cur[idx])
        lam[idx] = np.where(better, l / 3.0, l * 5.0)
        small = (np.abs(dd) < 1e-2) & (np.abs(dt) < 1e-5)
        active[idx] = ~(small & better) & (lam[idx] < 1e8)
    return th, d, cur


def initial_thickness(spectra, theta_rad, peak_wl_nm, film_ior, substrate_ior, wavelengths_nm,
                      max_thickness_nm=1.5 * MAX_THICKNESS_NM):
    """Starting thickness per pixel for a known film index: the best order m of Eq. 29.

    Returns (N,) thickness in nm (the candidate ``m λ_peak / (2 sqrt(n2² - sin² θ))`` whose
    spectrum fits best).
    """
    dc, n2c, _ = _order_candidates(np.asarray(theta_rad, float), np.asarray(peak_wl_nm, float),
                                   [film_ior], max_thickness_nm)
    e = _sm.grid_sse(spectra, theta_rad, dc, n2c, substrate_ior, wavelengths_nm)
    return dc[np.arange(dc.shape[0]), np.argmin(e, axis=1)]


def _joint_film_ior(S, th, d, n2, n3, wl, iterations=15):
    """Gauss-Newton over one shared n2 and every pixel's (θ, d) (Schur complement on n2)."""
    th, d = th.copy(), d.copy()
    n2_lo, n2_hi = 1.0, n3 - 1e-3
    sse_total = np.inf
    for _ in range(iterations):
        R, Jt, Jd, Jn = _sm.rs_spectra(th, d, n2, n3, wl, jac=("theta", "thickness", "film_ior"))
        r = S - R
        e = float(np.sum(r * r))
        dot = lambda x, y: np.einsum("ij,ij->i", x, y)  # noqa: E731
        a11, a12, a22 = dot(Jt, Jt) + 1e-12, dot(Jt, Jd), dot(Jd, Jd) + 1e-12
        det = a11 * a22 - a12 * a12
        c1, c2, en = dot(Jt, Jn), dot(Jd, Jn), dot(Jn, Jn)
        g1, g2, hn = dot(Jt, r), dot(Jd, r), dot(Jn, r)
        # A^{-1} c and A^{-1} g
        ac1, ac2 = (a22 * c1 - a12 * c2) / det, (a11 * c2 - a12 * c1) / det
        ag1, ag2 = (a22 * g1 - a12 * g2) / det, (a11 * g2 - a12 * g1) / det
        S_n = float(np.sum(en - (c1 * ac1 + c2 * ac2)))
        rhs = float(np.sum(hn - (c1 * ag1 + c2 * ag2)))
        dn = rhs / S_n if S_n > 0 else 0.0
        dn = float(np.clip(dn, -0.05, 0.05))
        dt = ag1 - ac1 * dn
        dd = ag2 - ac2 * dn
        step = 1.0
        for _ in range(6):
            n2_new = float(np.clip(n2 + step * dn, n2_lo, n2_hi))
            th_new = np.abs(th + step * np.clip(dt, -0.2, 0.2))
            d_new = np.maximum(d + step * np.clip(dd, -40, 40), 0.0)
            R2 = _sm.rs_spectra(th_new, d_new, n2_new, n3, wl)
            e2 = float(np.sum((S - R2) ** 2))
            if e2 < e:
                break
            step *= 0.5
        else:
            break
        converged = abs(n2_new - n2) < 1e-6
        th, d, n2, sse_total = th_new, d_new, n2_new, e2
        if converged:
            break
    return n2, th, d, sse_total


def estimate_film_ior(spectra, theta_rad, peak_wl_nm, substrate_ior, wavelengths_nm,
                      max_pixels=600):
    """One film index for the object, pooled over pixels at well-conditioned angles.

    The paper's (n2, m) search (Eqs. 28–30) is summed over the pooled pixels to pick the grid
    value and each pixel's order; a joint Gauss-Newton over the shared ``n2`` and every pixel's
    (θ, d) then refines it continuously.

    Parameters
    ----------
    spectra : (N, B) spectra of candidate pixels (with a peak).
    theta_rad, peak_wl_nm : (N,) first angles (from the peak) and peak wavelengths.

    Returns
    -------
    film_ior : float
    info : dict (pixels used, grid value)
    """
    S = np.asarray(spectra, dtype=np.float64)
    th = np.asarray(theta_rad, dtype=np.float64)
    lam = np.asarray(peak_wl_nm, dtype=np.float64)
    n = S.shape[0]
    if n == 0:
        raise UserError("spectral_s: no pixel shows a constructive-interference peak at a usable "
                        "angle (25°-65°), so the film index cannot be estimated")
    if n > max_pixels:
        sel = np.linspace(0, n - 1, max_pixels).round().astype(int)
        S, th, lam = S[sel], th[sel], lam[sel]
    grid = _film_ior_grid(substrate_ior)
    d, n2, _ = _order_candidates(th, lam, grid)
    sse = _sm.grid_sse(S, th, d, n2, substrate_ior, wavelengths_nm)
    G = grid.size
    sse_g = sse.reshape(S.shape[0], G, -1)
    best_m = np.argmin(sse_g, axis=2)  # (N, G)
    per_grid = np.min(sse_g, axis=2)
    total = np.sum(np.where(np.isfinite(per_grid), per_grid, 0.0), axis=0)
    g_best = int(np.argmin(total))
    n2_grid = float(grid[g_best])
    rows = np.arange(S.shape[0])
    d0 = d.reshape(S.shape[0], G, -1)[rows, g_best, best_m[:, g_best]]
    ok = np.isfinite(d0)
    n2_fit, _, _, _ = _joint_film_ior(S[ok], th[ok], d0[ok], n2_grid, substrate_ior,
                                      np.asarray(wavelengths_nm, dtype=np.float64))
    return n2_fit, {"film_ior_grid": n2_grid, "film_ior_pixels": int(ok.sum())}


# ---------------------------------------------------------------------------
# Methods
# ---------------------------------------------------------------------------


def _peaks(cube, mask, wl):
    spectra = cube[mask]
    pk = find_peaks(spectra, wl)
    stats = {
        "peak_one": int(np.sum(pk.status == PEAK_OK)),
        "peak_several": int(np.sum(pk.status == PEAK_SEVERAL)),
        "peak_none": int(np.sum(pk.status == PEAK_NONE)),
    }
    return spectra, pk, stats


def reconstruct_kobayashi(cube, wavelengths_nm, substrate_ior, mask):
    """The paper's method as published (see the module docstring)."""
    t = {}
    t0 = time.perf_counter()
    spectra, pk, stats = _peaks(cube, mask, wavelengths_nm)
    check_peak_assumption(spectra, substrate_ior, pk.noise)
    theta = _sm.angle_from_peak(pk.value, substrate_ior)
    t["peaks_and_angle"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    theta_img = np.full(mask.shape, np.nan)
    theta_img[mask] = theta
    normals, reached, height = _eik.characteristic_strips(theta_img, mask)
    t["normals_strips"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    n2_px, d_px, _ = kobayashi_search(spectra, theta, pk.wavelength_nm, substrate_ior, wavelengths_nm)
    t["search_n2_m"] = time.perf_counter() - t0
    film_ior = float(np.nanmedian(n2_px)) if np.isfinite(n2_px).any() else float("nan")

    thickness = np.full(mask.shape, np.nan)
    thickness[mask] = d_px
    valid = mask & reached & np.isfinite(thickness)
    inc = np.degrees(theta_img)
    info = {"peaks": stats, "timings_s": t}
    return SpectralEstimate(normals=normals, thickness_nm=thickness, valid=valid, film_ior=film_ior,
                            incident_deg=inc, height=height, info=info)


def _init_no_peak(S, n2, n3, wl, d_guess):
    """Coarse (θ, d) grid for pixels without a peak: θ in 3° steps, d ± 60 nm (15 nm steps)
    around a guess; Levenberg-Marquardt refines from there."""
    thetas = np.radians(np.arange(0.0, 89.0, 3.0))
    offs = np.arange(-60.0, 60.1, 15.0)
    n = S.shape[0]
    best_t = np.zeros(n)
    best_d = np.array(d_guess, dtype=np.float64)
    best_e = np.full(n, np.inf)
    dd = np.maximum(best_d[:, None] + offs[None, :], 0.0)
    for t_ in thetas:
        e = _sm.grid_sse(S, np.full(n, t_), dd, np.full(dd.shape, n2), n3, wl)
        k = np.argmin(e, axis=1)
        ek = e[np.arange(n), k]
        better = ek < best_e
        best_e = np.where(better, ek, best_e)
        best_t = np.where(better, t_, best_t)
        best_d = np.where(better, dd[np.arange(n), k], best_d)
    return best_t, best_d


def _unfold_magnitude(observed, sigma):
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


def _fit_no_peak(spectra, mask, has, th_fit, d_fit, n2, n3, wl, stokes_noise, misfit=3.0, which=None):
    """(θ, d) of the object pixels without a peak (``~has``, or the pixels ``which``), by
    Levenberg-Marquardt started from the nearest pixel with a peak (the surface and the film
    are continuous); pixels whose fit stays ``misfit`` times above the noise's expected
    residual are restarted from the coarse grid of :func:`_init_no_peak` and keep the better
    fit.

    Returns θ, d and the normal equations (as :func:`_levenberg_marquardt`) of those pixels.
    """
    none = ~has if which is None else np.asarray(which, dtype=bool)
    S = spectra[none]
    nz = stokes_noise[none]
    if has.any():
        img = np.full(mask.shape, -1, dtype=np.int64)
        img[mask] = np.where(has, np.arange(has.size), -1)
        _, (ir, ic) = ndimage.distance_transform_edt(img < 0, return_indices=True)
        src = img[ir, ic][mask][none]
        t_start, d_start = th_fit[src], d_fit[src]
    else:
        t_start, d_start = _init_no_peak(S, n2, n3, wl, np.full(S.shape[0], 400.0))
    th, d, cur = _levenberg_marquardt(S, t_start, d_start, n2, n3, wl, stokes_noise=nz)
    bad = np.nonzero(cur[:, 5] > misfit * wl.size * np.maximum(nz, 1e-6) ** 2)[0]
    if has.any() and bad.size:
        tg, dg = _init_no_peak(S[bad], n2, n3, wl, d_start[bad])
        th_b, d_b, cur_b = _levenberg_marquardt(S[bad], tg, dg, n2, n3, wl, stokes_noise=nz[bad])
        better = cur_b[:, 5] < cur[bad, 5]
        th[bad[better]], d[bad[better]], cur[bad[better]] = th_b[better], d_b[better], cur_b[better]
    return th, d, cur


def _thickness_at(spectra, theta, th_fit, d_fit, neq, n2, n3, wl, stokes_noise, linear_deg=0.25):
    """Thickness per pixel at new angles ``theta`` (fitted at ``th_fit``, ``d_fit``).

    Near the fitted angle the best thickness follows it linearly, ``d(θ) = d_fit - a12/a22 Δθ``
    from the normal equations ``neq`` of the (θ, d) fit (the second-order term is below 0.01 nm
    within ``linear_deg``); pixels whose angle moved further are refitted (d alone) through
    the optics core, from the shifted value where that shift is small and from ``d_fit``
    otherwise.
    """
    dth = theta - th_fit
    with np.errstate(divide="ignore", invalid="ignore"):
        shift = np.nan_to_num(np.where(neq[:, 2] > 0, -neq[:, 1] / neq[:, 2] * dth, 0.0))
    d = np.where(np.abs(shift) <= 10.0, np.maximum(d_fit + shift, 0.0), d_fit)
    redo = np.nonzero(np.abs(dth) > np.radians(linear_deg))[0]
    if redo.size:
        _, d[redo], _ = _levenberg_marquardt(spectra[redo], theta[redo], d[redo], n2, n3, wl,
                                             iterations=6, fit_theta=False,
                                             stokes_noise=stokes_noise[redo])
    return d


def reconstruct_eikonal(cube, wavelengths_nm, substrate_ior, mask, smoothness=10.0, angle_floor_deg=0.2,
                        condition_scale=2.0, noise_scale=1.0, misfit=3.0):
    """The default method (see the module docstring)."""
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    n3 = float(substrate_ior)
    t = {}
    t0 = time.perf_counter()
    spectra, pk, stats = _peaks(cube, mask, wl)
    check_peak_assumption(spectra, n3, pk.noise)
    peak_val = np.where(np.isfinite(pk.mean_value), pk.mean_value, pk.value)
    theta_peak = _sm.angle_from_peak(peak_val, n3)
    t["peaks"] = time.perf_counter() - t0

    # 1. the film index, once for the object
    t0 = time.perf_counter()
    use = np.isfinite(theta_peak) & (theta_peak > np.radians(25)) & (theta_peak < np.radians(65))
    n2, n2_info = estimate_film_ior(spectra[use], theta_peak[use], pk.wavelength_nm[use], n3, wl)
    t["film_ior"] = time.perf_counter() - t0

    # 2. (θ, d) per pixel. The capture is S0 + sqrt(S1² + S2²); its noise bias is modelled
    # with the S1/S2 noise of a four-angle rotating polarizer, about the band noise of the
    # s spectrum where the light is barely polarized (where the bias matters)
    t0 = time.perf_counter()
    stokes_noise = noise_scale * pk.noise
    has = np.isfinite(theta_peak)
    d0 = np.full(theta_peak.shape, np.nan)
    if has.any():
        d0[has] = initial_thickness(spectra[has], theta_peak[has], pk.wavelength_nm[has], n2, n3, wl)
    th0 = np.where(has, theta_peak, 0.0)
    # pixels with a peak first; they seed the others
    th_fit = np.zeros_like(th0)
    d_fit = np.zeros_like(th0)
    neq = np.zeros((th0.size, 6))  # normal equations at the fit, [a11 a12 a22 g1 g2 sse]
    if has.any():
        th_fit[has], d_fit[has], neq[has] = _levenberg_marquardt(
            spectra[has], th0[has], d0[has], n2, n3, wl, stokes_noise=stokes_noise[has])
    none = ~has
    if none.any():
        th_fit[none], d_fit[none], neq[none] = _fit_no_peak(
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
        th_r, d_r, neq_r = _fit_no_peak(spectra, mask, has & ~poor, th_fit, d_fit, n2, n3, wl, stokes_noise,
                                        misfit=misfit, which=redo)
        better = neq_r[:, 5] < neq[redo, 5]
        idx = np.nonzero(redo)[0][better]
        th_fit[idx], d_fit[idx], neq[idx] = th_r[better], d_r[better], neq_r[better]
    stats["refit_poor_peak"] = int(poor.sum())
    sig = _sigma_theta(neq_surf, wl.size)
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
    slope_t = np.where(mask, _unfold_magnitude(slope, np.where(mask, sig_slope, 1.0)), 0.0)
    z = _eik.refine_height(z0, slope_t, weight, mask, smoothness=smoothness)
    p, q = _eik.height_gradient(z, mask)
    theta_z = np.arctan(np.hypot(p, q))
    # blend: the pixel's own angle where it is precise, the surface's elsewhere
    sig_z = np.radians(1.0)
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
    d_fin = _thickness_at(spectra, theta_fin[mask], th_fit, d_fit, neq, n2, n3, wl, stokes_noise)
    t["thickness"] = time.perf_counter() - t0
    thickness = np.full(mask.shape, np.nan)
    thickness[mask] = d_fin
    valid = mask & np.isfinite(thickness) & np.isfinite(z)
    info = {"peaks": stats, "timings_s": t, **n2_info,
            "seeds": seed_kind, "smoothness": smoothness}
    return SpectralEstimate(normals=normals, thickness_nm=thickness, valid=valid, film_ior=float(n2),
                            incident_deg=np.degrees(theta_fin), height=z, info=info)


#: method name → function(cube, wavelengths_nm, substrate_ior, mask) -> SpectralEstimate
METHODS = {
    "eikonal": reconstruct_eikonal,
    "kobayashi": reconstruct_kobayashi,
}
DEFAULT_METHOD = "eikonal"
#: the paper's method as published
PAPER_METHOD = "kobayashi"
#: other names accepted for a method (the same ``paper`` / ``default`` as ``reconstruct rgb``)
ALIASES = {"published": PAPER_METHOD, "paper": PAPER_METHOD, "default": DEFAULT_METHOD}


def _method_name(method):
    """The registry name of ``method`` (None: the default); :class:`UserError` when unknown."""
    name = DEFAULT_METHOD if method is None else str(method)
    name = ALIASES.get(name, name)
    if name not in METHODS:
        raise UserError(f"--method: unknown spectral method {method!r}, expected one of "
                        f"{', '.join(sorted(list(METHODS) + list(ALIASES)))}")
    return name


def reconstruct_spectral(cube, wavelengths_nm, substrate_ior, mask=None, method=None, pixel_size=1.0):
    """Estimate normals, film index and thickness from an s-polarized spectral cube.

    Parameters
    ----------
    cube : (H, W, B) s reflectance per band.
    wavelengths_nm : (B,) band centres.
    substrate_ior : float, the substrate index n3 (> 1).
    mask : (H, W) bool, optional; from the data (:func:`object_mask`) if not given.
    method : str, a key of :data:`METHODS` or :data:`ALIASES` (default :data:`DEFAULT_METHOD`).
    pixel_size : float
        Width of a pixel in scene units (``meta.json`` ``projection.pixel_size``): the height
        field, integrated from ``|∇z| = tan θ`` on the pixel grid, is scaled by it so that it
        is in the same unit as the pixel positions (1: both in pixels).

    Returns
    -------
    SpectralEstimate
    """
    name = _method_name(method)
    cube, wl = _check_cube(cube, wavelengths_nm)
    if not (substrate_ior > 1.0):
        raise UserError(f"--substrate-ior: expected an index above 1, got {substrate_ior}")
    if mask is None:
        mask = object_mask(cube)
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != cube.shape[:2]:
        raise UserError(f"--mask: shape {mask.shape} does not match the images {cube.shape[:2]}")
    if mask.sum() < 20:
        raise UserError("spectral_s: fewer than 20 object pixels (nothing reflects above the background)")
    if not (np.isfinite(pixel_size) and pixel_size > 0):
        raise UserError(f"projection.pixel_size: expected a positive number, got {pixel_size}")
    t0 = time.perf_counter()
    est = METHODS[name](cube, wl, float(substrate_ior), mask)
    if est.height is not None:
        est.height = est.height * float(pixel_size)
    est.info["timings_s"]["total"] = time.perf_counter() - t0
    est.info["object_pixels"] = int(mask.sum())
    est.info["method"] = name
    return est


def _meta_pixel_size(meta, where):
    """``projection.pixel_size`` of ``meta.json`` (scene units per pixel), None when absent."""
    proj = meta.get("projection")
    if not isinstance(proj, dict) or proj.get("pixel_size") is None:
        return None
    value = proj["pixel_size"]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (np.isfinite(value) and value > 0):
        raise UserError(f"{where}: 'projection.pixel_size' must be a positive number, got {value!r}")
    return float(value)


def _check_dielectric_substrate(meta, where):
    """Refuse an absorbing substrate: the capture is then ``max(R_s, R_p)``, not ``R_s``."""
    k = meta.get("substrate_k", 0.0)
    try:
        k = float(k if k is not None else 0.0)
    except (TypeError, ValueError):
        raise UserError(f"{where}: 'substrate_k' must be a number, got {k!r}") from None
    if k > 0:
        raise UserError(f"{where}: substrate_k = {k:g} (absorbing substrate); the spectral method "
                        f"assumes a dielectric substrate, where spectral_s = S0 + sqrt(S1² + S2²) is R_s "
                        f"(on an absorbing one it is max(R_s, R_p))")


def cli_main(args):
    """``thinfilm reconstruct spectral DATASET --out DIR [--substrate-ior N3] [--method NAME] [--mask M]``."""
    from thinfilm.dataset import read_dataset

    from .estimate import write_estimate

    t_all = time.perf_counter()
    _method_name(getattr(args, "method", None))  # an unknown method fails before any reading
    t0 = time.perf_counter()
    ds = read_dataset(args.dataset, need=("spectral_s",), optional=())
    t_read = time.perf_counter() - t0
    meta_path = ds.path / "meta.json"
    _check_dielectric_substrate(ds.meta, meta_path)
    pixel_size = _meta_pixel_size(ds.meta, meta_path)
    n3 = args.substrate_ior if getattr(args, "substrate_ior", None) is not None else ds.meta.get("substrate_ior")
    if n3 is None:
        raise UserError(f"{meta_path}: no 'substrate_ior'; pass --substrate-ior")
    try:
        n3 = float(n3)
    except (TypeError, ValueError):
        raise UserError(f"{meta_path}: 'substrate_ior' must be a number, got {n3!r}") from None
    mask = read_mask_file(args.mask, ds.spectral_s.shape[:2]) if getattr(args, "mask", None) else None
    est = reconstruct_spectral(ds.spectral_s, ds.wavelengths_nm, n3, mask=mask,
                               method=getattr(args, "method", None), pixel_size=pixel_size or 1.0)
    timings = dict(est.info.pop("timings_s"))
    timings["read"] = t_read
    info = {
        "method": est.info.pop("method"),
        "film_ior": est.film_ior,
        "substrate_ior": n3,
        "timings_s": timings,
        "coverage": float(est.valid.sum() / max(1, est.info["object_pixels"])),
        "height_unit": "pixel" if pixel_size is None else "scene",
        **est.info,
    }
    t0 = time.perf_counter()
    height = est.height
    write_estimate(args.out, est.normals, est.thickness_nm, est.valid, info,
                   height=None if height is None else np.nan_to_num(height), pixel_size=pixel_size or 1.0)
    timings["write"] = time.perf_counter() - t0
    timings["wall"] = time.perf_counter() - t_all
    print(f"wrote {args.out} (method {info['method']}, film index {est.film_ior:.4f}, "
          f"{int(est.valid.sum())} pixels, {timings['wall']:.1f} s)")
    return 0
