"""Per-pixel inversion of the coherent thin-film model from polarized RGB.

Unknowns per pixel: zenith θ (carried as ``u = sin² θ``), film thickness d and azimuth φ
(modulo 180°: the polarizer cannot tell φ from φ + 180°). Observations: camera RGB behind
the polarizer at K ≥ 3 angles. All K × 3 values are fitted together with the model of
:class:`~thinfilm.reconstruction.rgb_model.FilmCamera`:

1. **Coarse search** over a table of model RGB ``(S0, P)`` on a (θ, d) grid; for every table
   entry the best φ has a closed form, so the whole table is scored with a few matrix
   products. The best entries from distinct thickness basins are kept (colours repeat along
   thickness, Fig. 5 of the paper).
2. **Refinement**: a vectorized Levenberg–Marquardt on the K × 3 intensity residuals of all
   pixels at once, from each kept candidate; the lowest final cost wins.

Both steps call the optics core through the model; nothing here re-implements physics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .polarization import fit_stokes, stokes_design_matrix
from .rgb_model import FilmCamera

__all__ = ["CoarseTable", "PixelFit", "PixelPrior", "build_table", "coarse_search", "refine_pixels", "invert_pixels",
           "model_intensities"]


@dataclass
class CoarseTable:
    """Model RGB on a (zenith, thickness) grid: ``S0``, ``P`` of shape (Z, D, 3)."""

    zenith_deg: np.ndarray
    thickness_nm: np.ndarray
    S0: np.ndarray
    P: np.ndarray


@dataclass
class PixelFit:
    """Per-pixel result: arrays of shape (N,). ``azimuth_deg`` in [0, 180) (the 180° ambiguity
    is left open); ``cost`` is the sum of squared residuals (weighted intensities, plus any
    prior terms), ``data_cost`` the intensity part alone;
    ``info_u``, ``info_d`` … the Gauss–Newton information ``JᵀJ`` at the optimum (N, 3, 3) in
    the order (u, d, φ)."""

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
                zenith_step_deg: float = 1.0, thickness_step_nm: float = 3.0) -> CoarseTable:
    """Tabulate model RGB over zenith ∈ [0, zenith_max] and thickness ∈ range (inclusive)."""
    lo, hi = (float(v) for v in thickness_range_nm)
    # Reflectance rises steeply towards grazing incidence: finer steps above 70°.
    zen = np.arange(0.0, min(70.0, zenith_max_deg) + 1e-9, zenith_step_deg)
    if zenith_max_deg > 70.0:
        zen = np.unique(np.concatenate([zen, np.arange(70.0, zenith_max_deg + 1e-9, zenith_step_deg / 4)]))
    n = max(2, int(round((hi - lo) / thickness_step_nm)) + 1)
    thick = np.linspace(lo, hi, n)
    S0, P = model.rgb_s0_p(np.cos(np.radians(zen))[:, None], thick[None, :])
    return CoarseTable(zen, thick, S0, P)


def coarse_search(table: CoarseTable, S0, S1, S2, angles_deg, n_candidates: int = 3,
                  basin_nm: float = 40.0, chunk: int = 256):
    """Best table entries per pixel, from distinct thickness basins.

    Parameters
    ----------
    S0, S1, S2 : (N, 3) observed RGB Stokes parameters.
    angles_deg : the polarizer angles (to weight S0 against S1/S2 as the intensity
        least-squares cost does).
    n_candidates : how many entries to keep, each more than ``basin_nm`` in thickness from
        the ones kept before it.

    Returns
    -------
    zenith_deg, thickness_nm, azimuth_deg, cost : arrays (N, n_candidates).
    """
    A = stokes_design_matrix(angles_deg)
    M = A.T @ A
    w0, w1 = M[0, 0], 0.5 * (M[1, 1] + M[2, 2])
    Z, D = table.S0.shape[:2]
    tS0 = table.S0.reshape(-1, 3)
    tP = table.P.reshape(-1, 3)
    t_norm = w0 * np.sum(tS0 ** 2, axis=1) + w1 * np.sum(tP ** 2, axis=1)
    thick = np.broadcast_to(table.thickness_nm[None, :], (Z, D)).ravel()
    zen = np.broadcast_to(table.zenith_deg[:, None], (Z, D)).ravel()
    N = S0.shape[0]
    out = [np.empty((N, n_candidates)) for _ in range(4)]
    f32 = np.float32
    tS0w, tPT = (2 * w0 * tS0.T).astype(f32), tP.T.astype(f32)
    t_norm = t_norm.astype(f32)
    for i in range(0, N, chunk):
        s0, s1, s2 = S0[i:i + chunk], S1[i:i + chunk], S2[i:i + chunk]
        Y1 = s1.astype(f32) @ tPT
        Y2 = s2.astype(f32) @ tPT
        cost = np.multiply(Y1, Y1)
        cost += Y2 * Y2
        np.sqrt(cost, out=cost)
        cost *= f32(-2 * w1)
        cost -= s0.astype(f32) @ tS0w
        cost += t_norm[None, :]
        const = w0 * np.sum(s0 ** 2, axis=1) + w1 * np.sum(s1 ** 2 + s2 ** 2, axis=1)
        n = cost.shape[0]
        rows = np.arange(n)
        cost = cost.reshape(n, Z, D)
        jz = np.argmin(cost, axis=1)  # best zenith row for every thickness column
        cd = np.take_along_axis(cost, jz[:, None, :], axis=1)[:, 0, :]  # (n, D)
        for k in range(n_candidates):
            jd = np.argmin(cd, axis=1)
            j = jz[rows, jd] * D + jd
            out[0][i:i + chunk, k] = zen[j]
            out[1][i:i + chunk, k] = thick[j]
            out[2][i:i + chunk, k] = np.mod(0.5 * np.degrees(np.arctan2(-Y2[rows, j], -Y1[rows, j])), 180.0)
            out[3][i:i + chunk, k] = np.maximum(cd[rows, jd] + const, 0.0)
            if k + 1 < n_candidates:
                near = np.abs(table.thickness_nm[None, :] - table.thickness_nm[jd][:, None]) <= basin_nm
                cd[near] = np.inf
    return tuple(out)


def model_intensities(model: FilmCamera, u, d, phi_rad, angles_rad):
    """Model RGB behind each polarizer: (N, K, 3), with ``P`` (N, 3) and ``S0`` (N, 3)."""
    S0, P = model.rgb_s0_p(np.sqrt(np.clip(1.0 - u, 0.0, 1.0)), d)
    c = np.cos(2.0 * (phi_rad[:, None] - angles_rad[None, :]))  # (N, K)
    I = 0.5 * (S0[:, None, :] - P[:, None, :] * c[:, :, None])
    return I, S0, P


def _v_to_u_phi(x):
    """(v1, v2) = u (cos 2φ, sin 2φ) → (u, φ)."""
    return np.hypot(x[:, 0], x[:, 1]), 0.5 * np.arctan2(x[:, 1], x[:, 0])


def refine_pixels(model: FilmCamera, I_obs, angles_deg, zenith_deg, thickness_nm, azimuth_deg,
                  thickness_range_nm, zenith_max_deg: float = 89.5, weights=None, prior=None,
                  iterations: int = 40, step_tol_u: float = 1e-8, step_tol_nm: float = 1e-4):
    """Levenberg–Marquardt on all K × 3 intensity residuals of every pixel at once.

    The parameters are ``(v1, v2, d)`` with ``(v1, v2) = sin²θ (cos 2φ, sin 2φ)``: the
    model is smooth in them through normal incidence, where φ is undefined.

    Parameters
    ----------
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
    N = I_obs.shape[0]
    ang = np.radians(np.asarray(angles_deg, dtype=np.float64))
    lo, hi = (float(v) for v in thickness_range_nm)
    u_max = np.sin(np.radians(zenith_max_deg)) ** 2
    w = np.ones_like(I_obs) if weights is None else weights
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

    def evaluate(x, idx):
        """Residuals (n, R) and the model's (S0, P) at x."""
        u, phi = _v_to_u_phi(x)
        I, S0, P = model_intensities(model, u, x[:, 2], phi, ang)
        r = ((I_obs[idx] - I) * w[idx]).reshape(idx.size, -1)
        if prior is not None:
            r = np.concatenate([r, prior.residuals(u, phi, x[:, 2], idx)], axis=1)
        return r, S0, P

    def jacobian(x, S0, P, idx):
        """Chain rule through I = ½ (S0(u, d) - (P(u, d)/u) (v1 cos 2α + v2 sin 2α)), with
        ∂/∂u and ∂/∂d of (S0, P) by forward differences (two optics evaluations)."""
        n = idx.size
        u = np.hypot(x[:, 0], x[:, 1])
        d = x[:, 2]
        hu = np.where(u + 1e-7 > u_max, -1e-7, 1e-7)
        uh = u + hu
        S0u, Pu = model.rgb_s0_p(np.sqrt(np.clip(1.0 - uh, 0.0, 1.0)), d)
        hd = np.where(d + 1e-3 > hi, -1e-3, 1e-3)
        S0d, Pd = model.rgb_s0_p(np.sqrt(np.clip(1.0 - u, 0.0, 1.0)), d + hd)
        dS0_du = (S0u - S0) / hu[:, None]
        dP_du = (Pu - P) / hu[:, None]
        dS0_dd = (S0d - S0) / hd[:, None]
        dP_dd = (Pd - P) / hd[:, None]
        tiny = u < 1e-7
        us = np.where(tiny, 1.0, u)
        Q = np.where(tiny[:, None], Pu / uh[:, None], P / us[:, None])       # P / u
        dQ_du = np.where(tiny[:, None], 0.0, (dP_du - Q) / us[:, None])
        e1 = np.where(tiny, 0.0, x[:, 0] / us)                                  # ∂u/∂v
        e2 = np.where(tiny, 0.0, x[:, 1] / us)
        m = x[:, 0:1] * c2a[None, :] + x[:, 1:2] * s2a[None, :]                 # (n, K) = u cos 2(φ-α)
        mm = m[:, :, None]
        dI_dv1 = 0.5 * (e1[:, None, None] * (dS0_du[:, None, :] - dQ_du[:, None, :] * mm)
                        - Q[:, None, :] * c2a[None, :, None])
        dI_dv2 = 0.5 * (e2[:, None, None] * (dS0_du[:, None, :] - dQ_du[:, None, :] * mm)
                        - Q[:, None, :] * s2a[None, :, None])
        dI_dd = 0.5 * (dS0_dd[:, None, :] - (dP_dd / us[:, None])[:, None, :] * mm
                       * np.where(tiny, 0.0, 1.0)[:, None, None])
        wi = w[idx]
        J = -np.stack([(dI_dv1 * wi).reshape(n, -1), (dI_dv2 * wi).reshape(n, -1),
                       (dI_dd * wi).reshape(n, -1)], axis=-1)
        if prior is not None:
            u0, phi0 = _v_to_u_phi(x)
            base = prior.residuals(u0, phi0, d, idx)
            Jp = np.empty(base.shape + (3,))
            for col, h in ((0, 1e-7), (1, 1e-7), (2, 1e-3)):
                xh = x.copy()
                xh[:, col] += h
                uu, pp = _v_to_u_phi(xh)
                Jp[:, :, col] = (prior.residuals(uu, pp, xh[:, 2], idx) - base) / h
            J = np.concatenate([J, Jp], axis=1)
        return J

    all_idx = np.arange(N)
    r, S0, P = evaluate(x, all_idx)
    cost = np.sum(r ** 2, axis=1)
    lam = np.full(N, 1e-3)
    active = np.ones(N, dtype=bool)
    JtJ = np.zeros((N, 3, 3))
    for it in range(iterations + 1):
        idx = np.nonzero(active)[0]
        if idx.size == 0:
            break
        J = jacobian(x[idx], S0[idx], P[idx], idx)
        JtJ[idx] = np.einsum("nri,nrj->nij", J, J)
        if it == iterations:
            break
        g = np.einsum("nri,nr->ni", J, r[idx])
        diag = np.einsum("nii->ni", JtJ[idx])
        scale = np.maximum(diag, 1e-9 * (diag.max(axis=1, keepdims=True) + 1e-30))
        A = JtJ[idx] + (lam[idx][:, None] * scale)[:, :, None] * np.eye(3)[None]
        step = -np.linalg.solve(A, g[:, :, None])[:, :, 0]
        xn = project(x[idx] + step)
        rn, S0n, Pn = evaluate(xn, idx)
        cn = np.sum(rn ** 2, axis=1)
        better = cn < cost[idx]
        ib = idx[better]
        rel = (cost[idx] - cn)[better] / np.maximum(cost[ib], 1e-300)
        x[ib], r[ib], S0[ib], P[ib], cost[ib] = xn[better], rn[better], S0n[better], Pn[better], cn[better]
        lam[ib] = np.maximum(lam[ib] * 0.3, 1e-9)
        lam[idx[~better]] *= 10.0
        done = np.zeros(N, dtype=bool)
        small = (np.abs(step[better, :2]).max(axis=1) < step_tol_u) & (np.abs(step[better, 2]) < step_tol_nm)
        done[ib] = (rel < 1e-12) | small
        done[idx[~better]] = lam[idx[~better]] > 1e8
        active &= ~done
    u, phi = _v_to_u_phi(x)
    zen = np.degrees(np.arcsin(np.sqrt(np.clip(u, 0.0, 1.0))))
    data_cost = np.sum(r[:, :I_obs[0].size] ** 2, axis=1)
    return PixelFit(zen, np.mod(np.degrees(phi), 180.0), x[:, 2], cost, JtJ, data_cost)


def invert_pixels(model: FilmCamera, I_obs, angles_deg, thickness_range_nm, table: CoarseTable | None = None,
                  n_candidates: int = 3, weights=None, zenith_max_deg: float = 89.0,
                  competitive_ratio: float = 4.0):
    """Coarse table search then LM refinement from each candidate; keep the best.

    Parameters
    ----------
    I_obs : (N, K, 3) camera RGB behind each of the K polarizer angles.
    table : a :func:`build_table` for this model and thickness range (built when omitted).
    n_candidates : thickness basins tried per pixel; a basin other than the coarse best is
        refined only where its coarse cost is within ``competitive_ratio`` times the best one
        (plus the median best cost, the noise floor).

    Returns
    -------
    PixelFit
    """
    I_obs = np.asarray(I_obs, dtype=np.float64)
    if table is None:
        table = build_table(model, thickness_range_nm, zenith_max_deg)
    S0, S1, S2 = fit_stokes(np.moveaxis(I_obs, 1, 0), angles_deg)
    zc, dc, pc, cc = coarse_search(table, S0, S1, S2, angles_deg, n_candidates)
    w = None if weights is None else np.asarray(weights, dtype=np.float64)
    best = refine_pixels(model, I_obs, angles_deg, zc[:, 0], dc[:, 0], pc[:, 0], thickness_range_nm,
                         zenith_max_deg=zenith_max_deg + 0.5, weights=w)
    floor = np.median(cc[:, 0])
    for k in range(1, n_candidates):
        idx = np.nonzero(cc[:, k] <= competitive_ratio * (cc[:, 0] + floor))[0]
        if idx.size == 0:
            continue
        fit = refine_pixels(model, I_obs[idx], angles_deg, zc[idx, k], dc[idx, k], pc[idx, k],
                            thickness_range_nm, zenith_max_deg=zenith_max_deg + 0.5,
                            weights=None if w is None else w[idx])
        b = fit.cost < best.cost[idx]
        for name in ("zenith_deg", "azimuth_deg", "thickness_nm", "cost", "info", "data_cost"):
            getattr(best, name)[idx[b]] = getattr(fit, name)[b]
    return best
