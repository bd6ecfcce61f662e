"""Per-pixel inversion of the coherent thin-film model from polarized RGB.

Unknowns per pixel: zenith θ (carried as ``u = sin² θ``), film thickness d and azimuth φ
(modulo 180°: the polarizer cannot tell φ from φ + 180°). Observations: camera RGB behind
the polarizer at K ≥ 3 angles. All K × 3 values are fitted together with the model of
:class:`~thinfilm.reconstruction.rgb_model.FilmCamera`, through its spline tabulation
(:class:`~thinfilm.reconstruction.rgb_model.FilmTable`, built once per run from the optics
core, which reproduces the optics core to a few parts in 10⁶):

1. **Coarse search** over model RGB ``(S0, P)`` on a (θ, d) grid. In the feature space
   ``(√w0 S0, √w1 P)`` the intensity least-squares cost is a Euclidean distance once the
   azimuth is fixed; the azimuth is taken from the observation itself (the common direction
   of the three channels' linear polarization), both signs of ``P`` are tried, and the
   nearest table entries are found with a k-d tree. Their exact costs (best φ per entry, in
   closed form) then rank them, and the best entries from distinct thickness basins are kept
   (colours repeat along thickness, Fig. 5 of the paper).
2. **Refinement**: a vectorized Levenberg–Marquardt on the K × 3 intensity residuals of all
   pixels at once, with the spline's exact derivatives. A few steps from every candidate
   that is not hopeless, then the ones still competitive run to convergence; the lowest
   final cost wins.

Nothing here re-implements physics: every model value comes from the optics core, through
the table.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thinfilm.core.conventions import fit_stokes, stokes_design_matrix

from .lm import levenberg_marquardt
from .rgb_model import FilmCamera, FilmTable, film_table

__all__ = ["InversionTable", "PixelFit", "PixelPrior", "build_table", "coarse_search", "refine_pixels",
           "invert_pixels", "pooled_thickness"]


@dataclass
class InversionTable:
    """What the inversion needs for one model and thickness range.

    Attributes
    ----------
    film : the spline tabulation of the model (:func:`~.rgb_model.film_table`), used by the
        refinement.
    zenith_deg, thickness_nm : (E,) the coarse search's entries.
    S0, P : (E, 3) model RGB at those entries (from ``film``).
    """

    film: FilmTable
    zenith_deg: np.ndarray
    thickness_nm: np.ndarray
    S0: np.ndarray
    P: np.ndarray

    @property
    def thickness_range_nm(self):
        return self.film.thickness_range_nm


@dataclass
class PixelFit:
    """Per-pixel result: arrays of shape (N,). ``azimuth_deg`` in [0, 180) (the 180° ambiguity
    is left open); ``cost`` is the sum of squared residuals (weighted intensities, plus any
    prior terms), ``data_cost`` the intensity part alone;
    ``info`` the Gauss–Newton information ``JᵀJ`` at the optimum (N, 3, 3) in the order
    (v1, v2, d) of :func:`refine_pixels`."""

    zenith_deg: np.ndarray
    azimuth_deg: np.ndarray
    thickness_nm: np.ndarray
    cost: np.ndarray
    info: np.ndarray
    data_cost: np.ndarray | None = None


@dataclass
class PixelPrior:
    """Gaussian priors for :func:`refine_pixels`, as residuals in the data's units.

    ``normal_xy`` (N, 2): expected image-plane part ``sin θ (cos φ, sin φ)`` of the normal,
    compared with whichever of ±(n_x, n_y) is nearer (polarization leaves the sign open);
    ``normal_weight`` (N,): residual multiplier (noise σ of the data / prior σ).
    ``thickness_nm``, ``thickness_weight`` (N,): the same for the thickness.
    """

    normal_xy: np.ndarray
    normal_weight: np.ndarray
    thickness_nm: np.ndarray
    thickness_weight: np.ndarray

    def residuals(self, u, phi, d, idx):
        s = np.sqrt(np.clip(u, 0.0, 1.0))
        n = np.stack([s * np.cos(phi), s * np.sin(phi)], axis=-1)
        n0 = self.normal_xy[idx]
        flip = np.sum(n * n0, axis=-1) < 0
        n[flip] *= -1.0
        rn = (n - n0) * self.normal_weight[idx][:, None]
        rd = (d - self.thickness_nm[idx]) * self.thickness_weight[idx]
        return np.concatenate([rn, rd[:, None]], axis=1)


def build_table(model: FilmCamera, thickness_range_nm, zenith_max_deg: float = 89.0,
                zenith_step_deg: float = 1.0, thickness_step_nm: float = 6.0,
                refine_zenith_max_deg: float = 89.5, phase_step_rad: float = 0.7) -> InversionTable:
    """Tabulate the model for :func:`invert_pixels`.

    The spline table (one pass of the optics core over its grid) covers zenith up to
    ``refine_zenith_max_deg`` and the thickness range; the coarse entries cover zenith ∈
    [0, zenith_max] (steps of ``zenith_step_deg``, four times finer above 70° where
    reflectance rises steeply) and thickness ∈ range (inclusive) in steps of about
    ``thickness_step_nm``, evaluated on the spline.
    """
    lo, hi = (float(v) for v in thickness_range_nm)
    film = film_table(model, (lo, hi), zenith_max_deg=refine_zenith_max_deg, phase_step_rad=phase_step_rad)
    zen = np.arange(0.0, min(70.0, zenith_max_deg) + 1e-9, zenith_step_deg)
    if zenith_max_deg > 70.0:
        zen = np.unique(np.concatenate([zen, np.arange(70.0, zenith_max_deg + 1e-9, zenith_step_deg / 4)]))
    n = max(2, int(round((hi - lo) / thickness_step_nm)) + 1)
    thick = np.linspace(lo, hi, n)
    Z, D = np.meshgrid(zen, thick, indexing="ij")
    c = np.cos(np.radians(Z.ravel()))
    S0, Q = film.s0_q(c, D.ravel())
    P = Q * (1.0 - c * c)[:, None]
    return InversionTable(film, Z.ravel(), D.ravel(), S0, P)


def _cost_weights(angles_deg):
    """Weights of S0 and of (S1, S2) in the intensity least-squares cost (exact for angles
    evenly spread over 180°, the mean for others)."""
    A = stokes_design_matrix(angles_deg)
    M = A.T @ A
    return float(M[0, 0]), float(0.5 * (M[1, 1] + M[2, 2]))


def coarse_search(table: InversionTable, S0, S1, S2, angles_deg, n_candidates: int = 3,
                  basin_nm: float = 40.0, neighbours: int = 32, eps: float = 0.3):
    """Best table entries per pixel, from distinct thickness basins.

    Parameters
    ----------
    S0, S1, S2 : (N, 3) observed RGB Stokes parameters.
    angles_deg : the polarizer angles (to weight S0 against S1/S2 as the intensity
        least-squares cost does).
    n_candidates : how many entries to keep, each more than ``basin_nm`` in thickness from
        the ones kept before it (fewer where the nearest entries hold fewer basins: the cost
        of a missing candidate is ``inf``).
    neighbours : entries looked up per pixel and sign of ``P`` (nearest in feature space).

    Returns
    -------
    zenith_deg, thickness_nm, azimuth_deg, cost : arrays (N, n_candidates).
    """
    from scipy.spatial import cKDTree

    w0, w1 = _cost_weights(angles_deg)
    S0, S1, S2 = (np.asarray(v, dtype=np.float64) for v in (S0, S1, S2))
    N = S0.shape[0]
    r0, r1 = np.sqrt(w0), np.sqrt(w1)
    tree = cKDTree(np.concatenate([r0 * table.S0, r1 * table.P], axis=1))
    # The channels' common polarization axis 2φ (mod 180°), and the signed P along it.
    psi = 0.5 * np.arctan2(2.0 * np.sum(S1 * S2, axis=1), np.sum(S1 * S1 - S2 * S2, axis=1))
    p = S1 * np.cos(psi)[:, None] + S2 * np.sin(psi)[:, None]
    obs = np.concatenate([np.concatenate([r0 * S0, -r1 * p], axis=1),
                          np.concatenate([r0 * S0, r1 * p], axis=1)])
    k = min(neighbours, len(table.S0))
    _, idx = tree.query(np.nan_to_num(obs, nan=0.0, posinf=0.0, neginf=0.0), k=k, eps=eps, workers=-1)
    idx = np.minimum(np.asarray(idx).reshape(2, N, k).transpose(1, 0, 2).reshape(N, 2 * k), len(table.S0) - 1)
    # Exact costs of those entries, with the best azimuth of each: one batched product gives
    # S0·S0_e, S1·P_e and S2·P_e for every entry e.
    O = np.zeros((N, 6, 3))
    O[:, :3, 0], O[:, 3:, 1], O[:, 3:, 2] = S0, S1, S2
    Y = np.matmul(np.take(np.concatenate([table.S0, table.P], axis=1), idx, axis=0), O)   # (N, 2k, 3)
    Y1, Y2 = Y[..., 1], Y[..., 2]
    e_norm = w0 * np.sum(table.S0 ** 2, axis=1) + w1 * np.sum(table.P ** 2, axis=1)
    const = w0 * np.sum(S0 ** 2, axis=1) + w1 * np.sum(S1 ** 2 + S2 ** 2, axis=1)
    cost = e_norm[idx] - 2.0 * w0 * Y[..., 0] - 2.0 * w1 * np.hypot(Y1, Y2) + const[:, None]
    cost = np.maximum(cost, 0.0)
    thick = table.thickness_nm[idx]
    rows = np.arange(N)
    out = [np.full((N, n_candidates), np.nan) for _ in range(3)] + [np.full((N, n_candidates), np.inf)]
    for j in range(n_candidates):
        e = np.argmin(cost, axis=1)
        ok = np.isfinite(cost[rows, e])
        ent = idx[rows, e]
        out[0][ok, j] = table.zenith_deg[ent][ok]
        out[1][ok, j] = table.thickness_nm[ent][ok]
        phi = np.mod(0.5 * np.degrees(np.arctan2(-Y2[rows, e], -Y1[rows, e])), 180.0)
        out[2][ok, j] = phi[ok]
        out[3][ok, j] = cost[rows, e][ok]
        if j + 1 < n_candidates:
            cost[np.abs(thick - thick[rows, e][:, None]) <= basin_nm] = np.inf
    return tuple(out)


def _v_to_u_phi(x):
    """(v1, v2) = u (cos 2φ, sin 2φ) → (u, φ)."""
    return np.hypot(x[:, 0], x[:, 1]), 0.5 * np.arctan2(x[:, 1], x[:, 0])


def refine_pixels(table: InversionTable, I_obs, angles_deg, zenith_deg, thickness_nm, azimuth_deg,
                  zenith_max_deg: float = 89.5, weights=None, prior=None,
                  iterations: int = 40, step_tol_u: float = 1e-8, step_tol_nm: float = 1e-4):
    """Levenberg–Marquardt on all K × 3 intensity residuals of every pixel at once.

    The parameters are ``(v1, v2, d)`` with ``(v1, v2) = sin²θ (cos 2φ, sin 2φ)``: the
    model ``I = ½ (S0(u, d) - Q(u, d) (v1 cos 2α + v2 sin 2α))`` (``Q = P / u``, ``u = |v|``)
    is smooth in them through normal incidence, where φ is undefined. Derivatives are the
    spline table's own (exact for the tabulated model).

    Parameters
    ----------
    table : :func:`build_table` for the model and thickness range (the thickness is kept
        inside the table's range, the zenith below ``zenith_max_deg``, which must not exceed
        the table's zenith range).
    I_obs : (N, K, 3) observed RGB behind each polarizer.
    zenith_deg, thickness_nm, azimuth_deg : (N,) start values.
    weights : optional (N, K, 3) residual weights (1/σ).
    prior : optional :class:`PixelPrior` (Gaussian priors on the normal's image-plane part and
        on the thickness, used by the surface-consistency step).
    iterations : maximum LM iterations.
    step_tol_u, step_tol_nm : a pixel stops once an accepted step moves ``sin² θ`` (times
        cos/sin 2φ) and the thickness by less than these.

    Returns
    -------
    PixelFit
    """
    film = table.film
    I_obs = np.asarray(I_obs, dtype=np.float64)
    ang = np.radians(np.asarray(angles_deg, dtype=np.float64))
    lo, hi = film.thickness_range_nm
    u_max = min(np.sin(np.radians(zenith_max_deg)) ** 2, 1.0 - film.cos_range[0] ** 2)
    w = None if weights is None else np.asarray(weights, dtype=np.float64)
    u0 = np.clip(np.sin(np.radians(zenith_deg)) ** 2, 0.0, u_max)
    phi0 = np.radians(azimuth_deg)
    x = np.stack([u0 * np.cos(2 * phi0), u0 * np.sin(2 * phi0),
                  np.clip(np.asarray(thickness_nm, dtype=np.float64), lo, hi)], axis=-1)

    def project(x):
        u = np.hypot(x[:, 0], x[:, 1])
        f = np.where(u > u_max, u_max / np.maximum(u, 1e-300), 1.0)
        x[:, 0] *= f
        x[:, 1] *= f
        x[:, 2] = np.clip(x[:, 2], lo, hi)
        return x

    c2a, s2a = np.cos(2 * ang), np.sin(2 * ang)
    n_data = I_obs[0].size

    def evaluate(x, idx):
        """Residuals (n, R) and Jacobian (n, R, 3) at x."""
        n = idx.size
        u = np.hypot(x[:, 0], x[:, 1])
        cos = np.sqrt(np.clip(1.0 - u, 0.0, 1.0))
        S0, Q, S0c, Qc, S0d, Qd = film.s0_q(cos, x[:, 2], derivatives=True)
        dc_du = (-0.5 / np.maximum(cos, 1e-12))[:, None]
        S0u, Qu = S0c * dc_du, Qc * dc_du
        m = (x[:, 0:1] * c2a[None, :] + x[:, 1:2] * s2a[None, :])[:, :, None]       # (n, K, 1)
        I = 0.5 * (S0[:, None, :] - Q[:, None, :] * m)
        tiny = u < 1e-12
        us = np.where(tiny, 1.0, u)
        e1 = np.where(tiny, 0.0, x[:, 0] / us)[:, None, None]                       # ∂u/∂v
        e2 = np.where(tiny, 0.0, x[:, 1] / us)[:, None, None]
        g = S0u[:, None, :] - Qu[:, None, :] * m                                    # ∂(2I)/∂u
        J = np.empty((n, I.shape[1], 3, 3))
        J[..., 0] = -0.5 * (e1 * g - Q[:, None, :] * c2a[None, :, None])
        J[..., 1] = -0.5 * (e2 * g - Q[:, None, :] * s2a[None, :, None])
        J[..., 2] = -0.5 * (S0d[:, None, :] - Qd[:, None, :] * m)
        r = I_obs[idx] - I
        if w is not None:
            r = r * w[idx]
            J = J * w[idx][..., None]
        r = r.reshape(n, -1)
        J = J.reshape(n, -1, 3)
        if prior is not None:
            u0, p0 = _v_to_u_phi(x)
            base = prior.residuals(u0, p0, x[:, 2], idx)
            Jp = np.empty(base.shape + (3,))
            for col, h in ((0, 1e-7), (1, 1e-7), (2, 1e-3)):
                xh = x.copy()
                xh[:, col] += h
                uu, pp = _v_to_u_phi(xh)
                Jp[:, :, col] = (prior.residuals(uu, pp, xh[:, 2], idx) - base) / h
            r = np.concatenate([r, base], axis=1)
            J = np.concatenate([J, Jp], axis=1)
        return r, J

    def normal_equations(x, idx):
        r, J = evaluate(x, idx)
        H = np.matmul(J.transpose(0, 2, 1), J)
        g = np.matmul(J.transpose(0, 2, 1), r[:, :, None])[:, :, 0]
        return H, g, np.sum(r ** 2, axis=1), np.sum(r[:, :n_data] ** 2, axis=1)

    fit = levenberg_marquardt(x, normal_equations, iterations, project=project,
                              step_tol=np.array([step_tol_u, step_tol_u, step_tol_nm]), rel_tol=1e-12,
                              lam0=1e-3, lam_down=0.3, lam_up=10.0, lam_min=1e-9, floor_rel=1e-9)
    x = fit.x
    u, phi = _v_to_u_phi(x)
    zen = np.degrees(np.arcsin(np.sqrt(np.clip(u, 0.0, 1.0))))
    return PixelFit(zen, np.mod(np.degrees(phi), 180.0), x[:, 2], fit.cost, fit.H, fit.aux)


def invert_pixels(model: FilmCamera, I_obs, angles_deg, thickness_range_nm, table: InversionTable | None = None,
                  n_candidates: int = 5, weights=None, zenith_max_deg: float = 89.0,
                  competitive_ratio: float = 4.0, screen_ratio: float = 50.0, screen_iterations: int = 3,
                  neighbours: int = 32, eps: float = 0.3, return_candidates: bool = False):
    """Coarse table search then LM refinement from each candidate; keep the best.

    Parameters
    ----------
    I_obs : (N, K, 3) camera RGB behind each of the K polarizer angles.
    table : a :func:`build_table` for this model and thickness range (built when omitted).
    n_candidates : thickness basins tried per pixel. Candidates whose coarse cost is within
        ``screen_ratio`` times the pixel's best (plus the median best cost, the noise floor)
        get ``screen_iterations`` LM steps; those then within ``competitive_ratio`` times the
        pixel's best (plus the new floor) are refined to convergence.
    neighbours, eps : of the k-d tree search (:func:`coarse_search`).
    return_candidates : also return every candidate refined to convergence (pixel index and
        :class:`PixelFit` of the candidates), for a choice among them by their neighbours.

    Returns
    -------
    PixelFit, or (PixelFit, (pixel index, PixelFit of the candidates))
    """
    I_obs = np.asarray(I_obs, dtype=np.float64)
    if table is None:
        table = build_table(model, thickness_range_nm, zenith_max_deg, refine_zenith_max_deg=zenith_max_deg + 0.5)
    N = I_obs.shape[0]
    S0, S1, S2 = fit_stokes(np.moveaxis(I_obs, 1, 0), angles_deg)
    zc, dc, pc, cc = coarse_search(table, S0, S1, S2, angles_deg, n_candidates, neighbours=neighbours, eps=eps)
    w = None if weights is None else np.asarray(weights, dtype=np.float64)
    zmax = zenith_max_deg + 0.5

    def refine(pix, cand, z, d, p, iterations):
        return refine_pixels(table, I_obs[pix], angles_deg, z, d, p, zenith_max_deg=zmax,
                             weights=None if w is None else w[pix], iterations=iterations)

    # Stage 1: a few LM steps from every candidate that is not hopeless, so that basins are
    # compared on costs near their minima rather than on the table's grid.
    floor = np.median(cc[:, 0])
    keep = np.isfinite(cc) & (cc <= screen_ratio * (cc[:, :1] + floor))
    pix, cand = np.nonzero(keep)
    fit = refine(pix, cand, zc[pix, cand], dc[pix, cand], pc[pix, cand], screen_iterations)
    cost = np.full(cc.shape, np.inf)
    cost[pix, cand] = fit.cost
    # Stage 2: the competitive ones to convergence; the lowest cost wins.
    best_cost = cost.min(axis=1)
    floor = np.median(best_cost)
    go = cost[pix, cand] <= competitive_ratio * (best_cost[pix] + floor)
    pix, cand = pix[go], cand[go]
    fit = refine(pix, cand, fit.zenith_deg[go], fit.thickness_nm[go], fit.azimuth_deg[go], 20)
    order = np.lexsort((fit.cost, pix))                      # by pixel, then cost
    first = np.ones(order.size, dtype=bool)
    first[1:] = pix[order][1:] != pix[order][:-1]
    sel = order[first]
    out = PixelFit(*(np.empty((N,) + np.shape(getattr(fit, name))[1:]) for name in
                     ("zenith_deg", "azimuth_deg", "thickness_nm", "cost", "info", "data_cost")))
    for name in ("zenith_deg", "azimuth_deg", "thickness_nm", "cost", "info", "data_cost"):
        getattr(out, name)[pix[sel]] = getattr(fit, name)[sel]
    if return_candidates:
        return out, (pix, fit)
    return out


def pooled_thickness(table: InversionTable, I_obs, angles_deg, zenith_deg, mask, sigma, sigma_px: float = 8.0,
                     zenith_rows: int = 5, max_zenith_deg: float = 65.0, cap_chi2: float = 9.0):
    """Each pixel's thickness from the evidence of its neighbourhood: for weak fringes, where
    a pixel alone leaves its order of interference open.

    Every pixel's misfit is profiled over the table's thickness grid (at each thickness the
    best of the table's zenith rows within ``zenith_rows`` of the pixel's zenith, and the best
    azimuth, in closed form as in :func:`coarse_search`), the profiles are averaged over a
    Gaussian window of ``sigma_px`` pixels on the mask (the thickness varies smoothly, the
    zenith need not), and each pixel takes the thickness of the lowest average.

    Returns (N,) thickness in nm for the mask pixels (in the mask's order).
    """
    from scipy import ndimage

    I_obs = np.asarray(I_obs, dtype=np.float64)
    S0, S1, S2 = fit_stokes(np.moveaxis(I_obs, 1, 0), angles_deg)
    w0, w1 = _cost_weights(angles_deg)
    zen = np.unique(table.zenith_deg)
    thick = np.unique(table.thickness_nm)
    Z, T = zen.size, thick.size
    S0t, Pt = table.S0.reshape(Z, T, 3), table.P.reshape(Z, T, 3)
    e_norm = w0 * np.sum(S0t ** 2, axis=-1) + w1 * np.sum(Pt ** 2, axis=-1)          # (Z, T)
    const = w0 * np.sum(S0 ** 2, axis=1) + w1 * np.sum(S1 ** 2 + S2 ** 2, axis=1)
    near = np.clip(np.searchsorted(zen, np.asarray(zenith_deg, dtype=np.float64)), 0, Z - 1)
    profile = np.full((S0.shape[0], T), np.inf)
    for off in range(-zenith_rows, zenith_rows + 1):
        r = np.clip(near + off, 0, Z - 1)
        y0 = np.einsum("ntc,nc->nt", S0t[r], S0)
        y1 = np.einsum("ntc,nc->nt", Pt[r], S1)
        y2 = np.einsum("ntc,nc->nt", Pt[r], S2)
        np.minimum(profile, e_norm[r] - 2.0 * w0 * y0 - 2.0 * w1 * np.hypot(y1, y2), out=profile)
    profile += const[:, None]
    # each pixel's profile relative to its own best, in units of the noise, capped: a pixel the
    # model cannot explain (an inter-reflection) cannot outvote its neighbours
    profile = np.minimum((profile - profile.min(axis=1, keepdims=True)) / sigma ** 2, cap_chi2)
    m = np.asarray(mask, dtype=bool)
    use = np.zeros(m.shape, dtype=bool)
    use[m] = np.asarray(zenith_deg) < max_zenith_deg
    vol = np.zeros(m.shape + (T,), dtype=np.float32)
    vol[use] = profile[use[m]]
    weight = ndimage.gaussian_filter(use.astype(np.float64), sigma_px)[m]
    pooled = ndimage.gaussian_filter(vol, (sigma_px, sigma_px, 0))[m] / np.maximum(weight, 1e-12)[:, None]
    return thick[np.argmin(pooled, axis=1)]
