"""Per-pixel fits of the spectral methods through the optics core (:mod:`.spectral_model`).

* the integer-order thickness candidates (the paper's Eqs. 28–29),
  :func:`initial_thickness`;
* :func:`fit_angle_thickness`: Levenberg-Marquardt of (θ, d), or d alone, to the whole
  spectrum (the shared solver of :mod:`.lm`), with the variance of θ;
* :func:`estimate_film_ior`: one film index for the object (the (n2, m) search pooled over
  pixels, then a joint Gauss-Newton over the shared ``n2`` and every pixel's (θ, d));
* the fits of pixels without a peak (:func:`fit_no_peak`) and the thickness at a new
  angle (:func:`thickness_at`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from thinfilm.core.errors import UserError

from . import spectral_model as _sm
from .lm import levenberg_marquardt, solve_arrow

__all__ = ["MAX_THICKNESS_NM", "FILM_IOR_MAX", "ThicknessRange", "thickness_limits", "fit_angle_thickness",
           "initial_thickness", "estimate_film_ior", "estimate_film_ior_either_side", "extrema_angles",
           "film_ior_grid", "order_candidates", "sigma_theta", "angle_thickness_lm", "init_no_peak",
           "fit_no_peak", "thickness_at", "joint_film_ior", "pooled_search", "FILM_IOR_SIGMA",
           "index_thickness_sigma"]

#: the paper's thickness span (its Fig. 5): the largest thickness of the published method's
#: (n2, m) search when no range is given
MAX_THICKNESS_NM = 1000.0


@dataclass(frozen=True)
class ThicknessRange:
    """The film thicknesses a spectral fit considers.

    Attributes
    ----------
    lo, hi : the range asked for (nm): ``--thickness-range``, else
        :data:`thinfilm.core.bands.SPECTRAL_THICKNESS_RANGE_NM`.
    max_optical_nm : the largest optical thickness ``n d`` the bands resolve
        (:func:`thinfilm.core.bands.resolved_optical_thickness_nm`).
    given : whether the range was given (else it is the default).
    """

    lo: float
    hi: float
    max_optical_nm: float = float("inf")
    given: bool = False

    def upper(self, film_ior: float) -> float:
        """The largest thickness considered for a film of index ``film_ior``."""
        return float(min(self.hi, self.max_optical_nm / max(float(film_ior), 1e-6)))

    def warn_if_cut(self, film_ior: float, what: str = "spectral") -> bool:
        """One warning when the bands cannot resolve the whole range given at ``film_ior``
        (the default range is cut silently: its top is *what the bands resolve*, recorded in
        the estimate's ``thickness_range_nm``); returns whether the range is cut."""
        top = self.upper(film_ior)
        if top >= self.hi:
            return False
        if not self.given:
            return True
        import warnings

        from thinfilm.core.errors import ThinfilmWarning

        asked = "the thickness range" if self.given else "the default thickness range"
        warnings.warn(f"{what}: the bands resolve interference fringes up to an optical thickness of "
                      f"{self.max_optical_nm:.0f} nm, {top:.0f} nm at the film index {film_ior:.3f}; thicker "
                      f"films of {asked} ({self.lo:g}-{self.hi:g} nm) are not considered (a finer spectral "
                      f"sampling resolves them)", ThinfilmWarning, stacklevel=3)
        return True


#: the uncertainty of an object's film index estimated as one number (the spectral defaults),
#: beyond its statistical error: a dispersive film (MgF2, water) fitted with a constant index,
#: and the other model errors. On the 20 scenes of the standard suite (96 px, their own seeds)
#: the defaults' index errors are 0.0001-0.0030 (median 0.0004), and with this value the
#: pooled share of pixels whose thickness error lies within 2 σ falls in the documented band
#: (``benchmarks/standard_suite.py`` prints it; checked on the random sweep's fresh seeds)
FILM_IOR_SIGMA = 0.002


def index_thickness_sigma(thickness_nm, theta_rad, film_ior, sigma_ior=FILM_IOR_SIGMA):
    """The thickness's standard deviation (nm) carried by an uncertain film index: the fringes
    fix the optical path ``d sqrt(n2² - sin² θ)``, so ``∂d/∂n2 = -d n2 / (n2² - sin² θ)``."""
    d = np.asarray(thickness_nm, dtype=np.float64)
    s2 = np.sin(np.asarray(theta_rad, dtype=np.float64)) ** 2
    return np.abs(d * film_ior / np.maximum(film_ior ** 2 - s2, 1e-6)) * sigma_ior


def thickness_limits(wavelengths_nm, thickness_range_nm=None, band_fwhm_nm: float = 0.0) -> ThicknessRange:
    """The :class:`ThicknessRange` of a spectral capture: ``thickness_range_nm`` (min, max) or
    the default, with what the bands (centres ``wavelengths_nm``, width ``band_fwhm_nm``)
    resolve."""
    from thinfilm.core.bands import SPECTRAL_THICKNESS_RANGE_NM, resolved_optical_thickness_nm

    given = thickness_range_nm is not None
    lo, hi = (float(v) for v in (thickness_range_nm if given else SPECTRAL_THICKNESS_RANGE_NM))
    if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 <= lo < hi):
        raise UserError(f"expected 0 <= MIN < MAX in nm, got {lo:g} {hi:g}", argument="thickness_range_nm")
    return ThicknessRange(lo, hi, resolved_optical_thickness_nm(wavelengths_nm, band_fwhm_nm), given)


#: largest film index the default method considers (above the substrate's: up to here)
FILM_IOR_MAX = 2.6


def film_ior_grid(substrate_ior, above=False, step=0.01):
    """Film indices to search: 1.00, 1.01, ... below ``n3`` (the paper's grid), or, with
    ``above``, from just above ``n3`` up to :data:`FILM_IOR_MAX`."""
    if not above:
        k = int(np.floor((substrate_ior - 1.0) / step + 1e-9))
        g = np.round(1.0 + step * np.arange(k + 1), 6)
        return g[g < substrate_ior - 1e-9]
    k = int(np.floor((FILM_IOR_MAX - substrate_ior) / step + 1e-9))
    return np.round(substrate_ior + step * np.arange(1, k + 1), 6)


def order_candidates(theta, peak_wl, n2_values, max_thickness_nm=MAX_THICKNESS_NM, min_thickness_nm=0.0,
                     max_optical_nm=float("inf")):
    """Eq. 29 thickness candidates ``d = m λ / (2 sqrt(n2² - sin² θ))`` for every n2 and m >= 1
    with ``min_thickness_nm <= d < max_thickness_nm`` and ``n2 d <= max_optical_nm`` (what the
    bands resolve): (N, K) thickness and film index, NaN-padded."""
    s2 = np.sin(theta) ** 2
    n2 = np.asarray(n2_values, dtype=np.float64)
    q2 = np.sqrt(np.maximum(n2[None, :] ** 2 - s2[:, None], 1e-12))  # (N, G)
    unit = peak_wl[:, None] / (2.0 * q2)  # d for m = 1
    top = np.minimum(float(max_thickness_nm), float(max_optical_nm) / n2)[None, :]
    with np.errstate(invalid="ignore"):
        m_max = np.nan_to_num(np.ceil(top / unit) - 1, nan=0).astype(int)
    M = max(1, int(np.max(m_max, initial=1)))
    m = np.arange(1, M + 1)
    d = unit[:, :, None] * m[None, None, :]  # (N, G, M)
    d = np.where((m[None, None, :] <= m_max[:, :, None]) & (d >= min_thickness_nm), d, np.nan)
    n2b = np.broadcast_to(n2[None, :, None], d.shape)
    return d.reshape(d.shape[0], -1), n2b.reshape(d.shape[0], -1), m


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
    th, d, cur = angle_thickness_lm(S, theta0, thickness0, film_ior, substrate_ior, wavelengths_nm,
                                      iterations, fit_theta, theta_max_deg, stokes_noise)
    return th, d, cur[:, 5], sigma_theta(cur, S.shape[1], fit_theta)


def sigma_theta(cur, bands, fit_theta=True):
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


def angle_thickness_lm(S, theta0, thickness0, film_ior, substrate_ior, wavelengths_nm,
                         iterations=12, fit_theta=True, theta_max_deg=89.5, stokes_noise=None):
    """The iterations of :func:`fit_angle_thickness` (the shared solver of :mod:`.lm`): final
    (θ, d) and, per pixel, the normal equations at that point, ``[a11 a12 a22 g1 g2 sse]``
    (θ first, then d; ``g`` = Jᵀr with J the model's Jacobian)."""
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    S = np.asarray(S, dtype=np.float64)
    n = S.shape[0]
    th_max = np.radians(theta_max_deg)
    noise = None if stokes_noise is None else np.broadcast_to(np.asarray(stokes_noise, float), (n,))
    jac = ("theta", "thickness") if fit_theta else ("thickness",)
    dot = lambda x, y: np.einsum("ij,ij->i", x, y)  # noqa: E731
    theta_fixed = np.array(theta0, dtype=np.float64)

    def normal_equations(x, idx):
        th_ = x[:, 0] if fit_theta else theta_fixed[idx]
        d_ = x[:, -1]
        nz = None if noise is None else noise[idx]
        out = _sm.rs_spectra(th_, d_, film_ior, substrate_ior, wl, jac=jac, stokes_noise=nz)
        r = S[idx] - out[0]
        Jd = out[-1]
        sse = dot(r, r)
        if fit_theta:
            Jt = out[1]
            a11, a12, a22 = dot(Jt, Jt), dot(Jt, Jd), dot(Jd, Jd)
            H = np.stack([np.stack([a11, a12], -1), np.stack([a12, a22], -1)], -2)
            g1, g2 = dot(Jt, r), dot(Jd, r)
            # the residual's Jacobian is minus the model's
            return H, -np.stack([g1, g2], -1), sse, None
        return dot(Jd, Jd)[:, None, None], -dot(Jd, r)[:, None], sse, None

    def project(x):
        if fit_theta:
            x[:, 0] = np.clip(np.abs(x[:, 0]), 0.0, th_max)
        x[:, -1] = np.maximum(x[:, -1], 0.0)
        return x

    # steps of d within a quarter period at the shortest wavelength (no order jumps)
    x0 = np.stack([theta_fixed, np.array(thickness0, dtype=np.float64)], -1) if fit_theta else \
        np.array(thickness0, dtype=np.float64)[:, None]
    fit = levenberg_marquardt(
        x0, normal_equations, iterations, project=project,
        max_step=[0.2, 40.0] if fit_theta else [40.0], step_tol=[1e-5, 1e-2] if fit_theta else [1e-2],
        lam0=1e-3, lam_down=1.0 / 3.0, lam_up=5.0, floor_rel=0.0, floor_abs=1e-18)
    H, g = fit.H, -fit.g
    if fit_theta:
        th, d = fit.x[:, 0], fit.x[:, 1]
        cur = np.stack([H[:, 0, 0], H[:, 0, 1], H[:, 1, 1], g[:, 0], g[:, 1], fit.cost], -1)
    else:
        th, d = theta_fixed, fit.x[:, 0]
        z = np.zeros(n)
        cur = np.stack([z, z, H[:, 0, 0], z, g[:, 0], fit.cost], -1)
    return th, d, cur


def initial_thickness(spectra, theta_rad, peak_wl_nm, film_ior, substrate_ior, wavelengths_nm,
                      max_thickness_nm=1.5 * MAX_THICKNESS_NM, limits: ThicknessRange | None = None):
    """Starting thickness per pixel for a known film index: the best order m of Eq. 29.

    Returns (N,) thickness in nm (the candidate ``m λ_peak / (2 sqrt(n2² - sin² θ))`` whose
    spectrum fits best). With ``limits`` the candidates span the :class:`ThicknessRange` at
    ``film_ior`` (and a tenth beyond its top, so that a film at the top finds its order)
    instead of ``max_thickness_nm``.
    """
    lo, opt = 0.0, float("inf")
    if limits is not None:
        lo, max_thickness_nm = limits.lo, 1.1 * limits.upper(film_ior)
    dc, n2c, _ = order_candidates(np.asarray(theta_rad, float), np.asarray(peak_wl_nm, float),
                                  [film_ior], max_thickness_nm, lo, opt)
    e = _sm.grid_sse(spectra, theta_rad, dc, n2c, substrate_ior, wavelengths_nm)
    return dc[np.arange(dc.shape[0]), np.argmin(e, axis=1)]


def joint_film_ior(S, th, d, n2, n3, wl, iterations=15, bounds=None):
    """Least squares over one shared n2 and every pixel's (θ, d): one problem of ``1 + 2 N``
    unknowns for :func:`thinfilm.reconstruction.lm.levenberg_marquardt`, its damped systems
    solved by the Schur complement on n2 (:func:`thinfilm.reconstruction.lm.solve_arrow`).
    ``S`` holds s spectra (N, B) or s then p spectra (N, 2 B); n2 stays within ``bounds``
    (default: below the substrate's index); steps are at most 0.05 in n2, 0.2 rad in θ and
    40 nm in d. Returns ``(n2, θ, d, sse)``."""
    th, d = np.asarray(th, dtype=np.float64), np.asarray(d, dtype=np.float64)
    N = th.size
    if N == 0:
        # the shared index would rest on nothing (its normal equations are zero)
        raise UserError("spectral: no pixel's spectrum fits an order of interference within the thickness "
                        "range, so the film index cannot be estimated")
    n2_lo, n2_hi = (1.0, n3 - 1e-3) if bounds is None else bounds
    with_p = S.shape[1] == 2 * np.size(wl)

    def split(x):
        return float(x[0, 0]), x[0, 1::2], x[0, 2::2]

    def normal_equations(x, idx):
        n2_, th_, d_ = split(x)
        R, Jt, Jd, Jn = _sm.rs_spectra(th_, d_, n2_, n3, wl, jac=("theta", "thickness", "film_ior"), with_p=with_p)
        r = R - S
        dot = lambda a, b: np.einsum("ij,ij->i", a, b)  # noqa: E731
        H = np.zeros((1, 1 + 2 * N, 1 + 2 * N))
        t, u = 1 + 2 * np.arange(N), 2 + 2 * np.arange(N)
        H[0, 0, 0] = np.sum(Jn * Jn)
        H[0, 0, t] = H[0, t, 0] = dot(Jn, Jt)
        H[0, 0, u] = H[0, u, 0] = dot(Jn, Jd)
        H[0, t, t] = dot(Jt, Jt) + 1e-12
        H[0, u, u] = dot(Jd, Jd) + 1e-12
        H[0, t, u] = H[0, u, t] = dot(Jt, Jd)
        g = np.empty((1, 1 + 2 * N))
        g[0, 0], g[0, t], g[0, u] = np.sum(Jn * r), dot(Jt, r), dot(Jd, r)
        return H, g, np.array([np.sum(r * r)]), None

    def project(x):
        x[:, 0] = np.clip(x[:, 0], n2_lo, n2_hi)
        x[:, 1::2] = np.abs(x[:, 1::2])
        x[:, 2::2] = np.maximum(x[:, 2::2], 0.0)
        return x

    x0 = np.empty((1, 1 + 2 * N))
    x0[0, 0], x0[0, 1::2], x0[0, 2::2] = n2, th, d
    max_step = np.empty(1 + 2 * N)
    max_step[0], max_step[1::2], max_step[2::2] = 0.05, 0.2, 40.0
    fit = levenberg_marquardt(x0, normal_equations, iterations, project=project, max_step=max_step,
                              floor_rel=0.0, floor_abs=1e-12, solve=lambda A, b: solve_arrow(A, b, 2),
                              converged=lambda step, H, cost, ok: ok & (np.abs(step[:, 0]) < 1e-6))
    n2_fit, th_fit, d_fit = split(fit.x)
    return n2_fit, th_fit.copy(), d_fit.copy(), float(fit.cost[0])


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
    grid = film_ior_grid(substrate_ior)
    d, n2, _ = order_candidates(th, lam, grid)
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
    n2_fit, _, _, _ = joint_film_ior(S[ok], th[ok], d0[ok], n2_grid, substrate_ior,
                                      np.asarray(wavelengths_nm, dtype=np.float64))
    return n2_fit, {"film_ior_grid": n2_grid, "film_ior_pixels": int(ok.sum())}


def extrema_angles(spectra_s, wavelengths_nm, substrate_ior, above):
    """The extrema where the film's round-trip phase is a multiple of 2π, where the
    reflectance is the bare substrate's whatever the film (Eq. 21): maxima of the s spectrum
    for a film below the substrate's index, minima above it. Returns the peak result
    (:func:`.peaks.find_peaks`, values positive) and the incident angle from the extremum's
    value (NaN where a pixel has none)."""
    from .peaks import find_peaks

    S = np.asarray(spectra_s, dtype=np.float64)
    pk = find_peaks(-S if above else S, wavelengths_nm)
    if above:
        pk.value, pk.mean_value, pk.all_value = -pk.value, -pk.mean_value, -pk.all_value
    val = np.where(np.isfinite(pk.mean_value), pk.mean_value, pk.value)
    return pk, _sm.angle_from_peak(val, substrate_ior)


def pooled_search(S, th, lam, n3, wl, grid, limits: ThicknessRange | None = None):
    """The (n2, m) search of Eqs. 28-30 summed over pooled pixels: total SSE per grid value,
    and each pixel's best thickness at every grid value (orders within ``limits``, else below
    :data:`MAX_THICKNESS_NM`)."""
    if limits is None:
        d, n2, _ = order_candidates(th, lam, grid)
    else:
        d, n2, _ = order_candidates(th, lam, grid, limits.hi, limits.lo, limits.max_optical_nm)
    sse = _sm.grid_sse(S, th, d, n2, n3, wl)
    G = grid.size
    sse_g = sse.reshape(S.shape[0], G, -1)
    best_m = np.argmin(sse_g, axis=2)
    per_grid = np.min(sse_g, axis=2)
    total = np.sum(np.where(np.isfinite(per_grid), per_grid, 1e3), axis=0)
    d_best = np.take_along_axis(d.reshape(S.shape[0], G, -1), best_m[..., None], axis=2)[..., 0]
    return total, d_best


def estimate_film_ior_either_side(spectra, wavelengths_nm, substrate_ior, max_pixels=160,
                                  angle_range_deg=(20.0, 70.0), coarse_step=0.04, max_candidates=4000,
                                  limits: ThicknessRange | None = None):
    """One film index for the object, below or above the substrate's, from the spectra.

    Which side holds is read from the physics of the spectra: below the substrate's index the
    extrema at the bare substrate's reflectance are the maxima, above it the minima; both
    hypotheses (angles from the maxima and 1.00 <= n2 < n3, or from the minima and
    n3 < n2 <= :data:`FILM_IOR_MAX`) are fitted, by the pooled (n2, m) search, to the same
    pixels (those with both extrema at well-conditioned angles), and the better fit wins.
    The winner is refined by the joint Gauss-Newton over the shared n2 and every pixel's
    (θ, d). Nothing assumes near-normal pixels.

    Parameters
    ----------
    spectra : (N, B) s spectra, or (N, 2 B) s then p spectra (a Stokes capture: both fitted).
    max_pixels : pixels pooled per hypothesis (evenly spread over those that qualify).
    max_candidates : pixels examined for extrema (evenly spread over the object).
    limits : the :class:`ThicknessRange` of the orders searched (default: below
        :data:`MAX_THICKNESS_NM`).

    Returns
    -------
    film_ior : float
    info : dict (``film_ior_above_substrate``, the pooled pixels, the grid value, the two
        hypotheses' mean squared residuals)

    Raises
    ------
    UserError
        When no pixel shows such an extremum at a usable angle.
    """
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    S_all = np.asarray(spectra, dtype=np.float64)
    if S_all.shape[0] > max_candidates:
        S_all = S_all[np.linspace(0, S_all.shape[0] - 1, max_candidates).round().astype(int)]
    b = wl.size
    lo, hi = np.radians(angle_range_deg)
    hyp = {}
    for above in (False, True):
        pk, th = extrema_angles(S_all[:, :b], wl, substrate_ior, above)
        use = np.isfinite(th) & (th > lo) & (th < hi)
        if use.sum() < 12:
            # an object with no pixel at a well-conditioned angle (a gentle sheet, a shallow
            # cap): whatever angles it has; the joint fit refines their angles with the index
            use = np.isfinite(th) & (th < np.radians(88.0))
        hyp[above] = (pk, th, use)
    both = hyp[False][2] & hyp[True][2]
    if both.sum() >= 12:
        pools = {False: both, True: both}
    else:
        pools = {k: v[2] for k, v in hyp.items()}
    results = {}
    for above in (False, True):
        idx = np.nonzero(pools[above])[0]
        if idx.size == 0:
            continue
        if idx.size > max_pixels:
            idx = idx[np.linspace(0, idx.size - 1, max_pixels).round().astype(int)]
        pk, th = hyp[above][0], hyp[above][1]
        S, t, lam = S_all[idx], th[idx], pk.wavelength_nm[idx]
        grid = film_ior_grid(substrate_ior, above, coarse_step)
        if grid.size == 0:
            continue
        coarse, _ = pooled_search(S, t, lam, substrate_ior, wl, grid, limits)
        g0 = float(grid[int(np.argmin(coarse))])
        fine = film_ior_grid(substrate_ior, above, 0.01)
        fine = fine[np.abs(fine - g0) <= coarse_step + 1e-9]
        total, d_best = pooled_search(S, t, lam, substrate_ior, wl, fine, limits)
        k = int(np.argmin(total))
        results[above] = (float(total[k]) / idx.size, float(fine[k]), S, t, d_best[:, k], lam)
    if not results:
        raise UserError("spectral_s: no pixel shows an interference extremum at a usable angle "
                        f"({angle_range_deg[0]:g}°-{angle_range_deg[1]:g}°), so the film index cannot be estimated")
    above = min(results, key=lambda a: results[a][0])
    _, n2_grid, S, t, d0, lam = results[above]
    ok = np.isfinite(d0)
    bounds = (substrate_ior + 1e-3, FILM_IOR_MAX) if above else (1.0, substrate_ior - 1e-3)
    n2_fit, _, _, sse = joint_film_ior(S[ok], t[ok], d0[ok], n2_grid, substrate_ior, wl, bounds=bounds)
    mirrored = None
    if not above:
        # Near normal incidence a film n2 below the substrate and one of n3 / n2 give the same
        # spectra (the two interfaces' amplitudes swap; n2 d is the same): only oblique
        # pixels tell them apart. Where the data cannot (the fits differ by less than the
        # noise), the larger index is taken: a film of n3 / n2 below sqrt(n3) is rare.
        # The mirrored index gets the same search as the first: its own orders from the pooled
        # (n2, m) search around n3 / n2 (the first fit's thicknesses scaled to it can sit a
        # fringe off at oblique pixels), then the joint fit.
        n2_m = substrate_ior / n2_fit
        if 1.0 < n2_m < substrate_ior - 1e-3 and abs(n2_m - n2_fit) > 0.02:
            fine = film_ior_grid(substrate_ior, False, 0.01)
            fine = fine[np.abs(fine - n2_m) <= coarse_step + 1e-9]
            total_m, d_best_m = pooled_search(S[ok], t[ok], lam[ok], substrate_ior, wl, fine, limits)
            k = int(np.argmin(total_m))
            d_m, n2_start = d_best_m[:, k], float(fine[k])
            keep = np.isfinite(d_m)
            if not np.all(keep):  # pixels the mirrored orders miss keep the scaled thickness
                d_m = np.where(keep, d_m, d0[ok] * n2_fit / n2_m)
            n2_mf, _, _, sse_m = joint_film_ior(S[ok], t[ok], d_m, n2_start, substrate_ior, wl, bounds=bounds)
            from .peaks import band_noise

            sigma2 = float(np.median(band_noise(S[ok, :b]))) ** 2
            indistinct = abs(sse_m - sse) < max(10.0 * sigma2, 0.02 * min(sse, sse_m))
            mirrored = {"film_ior": float(n2_mf), "sse_ratio": float(sse_m / max(sse, 1e-300))}
            if (sse_m < sse and not indistinct) or (indistinct and n2_mf > n2_fit):
                n2_fit = n2_mf
    info = {"film_ior_grid": n2_grid, "film_ior_pixels": int(ok.sum()), "film_ior_above_substrate": bool(above),
            "film_ior_fit_below": results.get(False, (None,))[0], "film_ior_fit_above": results.get(True, (None,))[0],
            "film_ior_mirrored": mirrored}
    return float(n2_fit), info



def init_no_peak(S, n2, n3, wl, d_guess):
    """Coarse (θ, d) grid for pixels without a peak: θ in 3° steps, d ± 60 nm (15 nm steps)
    around a guess; Levenberg-Marquardt refines from there."""
    thetas = np.radians(np.arange(0.0, 89.0, 3.0))
    offs = np.arange(-60.0, 60.1, 15.0)
    n = S.shape[0]
    t_n = thetas.size
    dd = np.maximum(np.asarray(d_guess, dtype=np.float64)[:, None] + offs[None, :], 0.0)
    # every (pixel, angle) pair as one row: one evaluation of the whole grid
    rows = np.repeat(np.arange(n), t_n)
    e = _sm.grid_sse(S[rows], np.tile(thetas, n), dd[rows], np.full((rows.size, offs.size), n2), n3, wl)
    e = e.reshape(n, t_n * offs.size)
    k = np.argmin(e, axis=1)
    return thetas[k // offs.size], dd[np.arange(n), k % offs.size]


def fit_no_peak(spectra, mask, has, th_fit, d_fit, n2, n3, wl, stokes_noise, misfit=3.0, which=None):
    """(θ, d) of the object pixels without a peak (``~has``, or the pixels ``which``), by
    Levenberg-Marquardt started from the nearest pixel with a peak (the surface and the film
    are continuous); pixels whose fit stays ``misfit`` times above the noise's expected
    residual are restarted from the coarse grid of :func:`init_no_peak` and keep the better
    fit.

    Returns θ, d and the normal equations (as :func:`angle_thickness_lm`) of those pixels.
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
        t_start, d_start = init_no_peak(S, n2, n3, wl, np.full(S.shape[0], 400.0))
    th, d, cur = angle_thickness_lm(S, t_start, d_start, n2, n3, wl, stokes_noise=nz)
    bad = np.nonzero(cur[:, 5] > misfit * wl.size * np.maximum(nz, 1e-6) ** 2)[0]
    if has.any() and bad.size:
        tg, dg = init_no_peak(S[bad], n2, n3, wl, d_start[bad])
        th_b, d_b, cur_b = angle_thickness_lm(S[bad], tg, dg, n2, n3, wl, stokes_noise=nz[bad])
        better = cur_b[:, 5] < cur[bad, 5]
        th[bad[better]], d[bad[better]], cur[bad[better]] = th_b[better], d_b[better], cur_b[better]
    return th, d, cur


def thickness_at(spectra, theta, th_fit, d_fit, neq, n2, n3, wl, stokes_noise, linear_deg=0.25):
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
        _, d[redo], _ = angle_thickness_lm(spectra[redo], theta[redo], d[redo], n2, n3, wl,
                                             iterations=6, fit_theta=False,
                                             stokes_noise=stokes_noise[redo])
    return d
