"""The paper's polarized-RGB method as published (Kobayashi et al., Sec. 4).

* zenith from the degree of polarization (Eq. 10) of the grey (RGB-mean) Stokes vector,
  inverted on the DOP curve of the paper's Eqs. 11–16 — the two interfaces summed
  *incoherently*, ``I_s = R_s(t) + T_s(t) R_s(b) T_s(b)`` (and the same for p), with the
  Fresnel terms taken from :func:`thinfilm.bsdf.optics.interface_amplitudes`; the two
  solutions either side of the Brewster angle told apart by the s-polarized intensity
  ``I_max`` (= (S0 + |S1, S2|) / 2 · 2) against its value at the Brewster angle (Sec. 4.2);
* azimuth from the angle of polarization, the s-direction being φ + 90° (Sec. 4.1, 4.3),
  the 180° ambiguity resolved outwards at the occluding boundary and propagated inwards
  (Sec. 4.3, :func:`~thinfilm.reconstruction.masks.resolve_azimuth`);
* thickness by least squares between the observed RGB (S0, the unpolarized appearance) and
  a table of simulated RGB over (zenith, thickness) within the thickness range, at the
  estimated zenith (Sec. 4.4; the table uses the coherent Airy model of the paper's Eq. 2
  through :mod:`thinfilm.bsdf.optics` and the dataset's camera and illuminant).

The paper's formulas take one film and one substrate index: a dispersive index enters as
its effective index (:meth:`thinfilm.core.film.Film.effective_index`).
"""

from __future__ import annotations

import time

import numpy as np

from thinfilm.core.conventions import angles_to_normals, aolp_deg, azimuth_from_aolp_deg, dolp, fit_stokes, \
    s_polarized
from thinfilm.core.io import Estimate
from thinfilm.core.progress import progress_iter

from .masks import resolve_azimuth
from .rgb_capture import RGBCapture

__all__ = ["incoherent_polarization_curve", "zenith_from_dop", "check_film_below_substrate", "reconstruct_kobayashi2023"]


def incoherent_polarization_curve(film_ior: float, substrate_ior: float, zenith_deg):
    """The paper's Eqs. 11–16: s and p intensities of the film with its two interfaces summed
    incoherently, ``I_s = R_s(t) + T_s(t) R_s(b) T_s(b)``, and the DOP ``(I_s - I_p)/(I_s + I_p)``.

    ``t`` is the air–film interface at the zenith angle, ``b`` the film–substrate interface at
    the refracted angle θ2 (Snell); ``T = 1 - R`` for these lossless interfaces, which equals
    the paper's Eqs. 15–16. The Fresnel amplitudes come from the optics core.

    Returns
    -------
    I_s, I_p, dop : arrays shaped like ``zenith_deg``.
    """
    from thinfilm.bsdf.optics import interface_amplitudes

    c1 = np.cos(np.radians(np.asarray(zenith_deg, dtype=np.float64)))
    rs_t, rp_t = interface_amplitudes(c1, 1.0, film_ior)
    sin2 = (1.0 - c1 ** 2) / film_ior ** 2
    c2 = np.sqrt(np.clip(1.0 - sin2, 0.0, 1.0))
    rs_b, rp_b = interface_amplitudes(c2, film_ior, substrate_ior)
    Rs_t, Rp_t = np.abs(rs_t) ** 2, np.abs(rp_t) ** 2
    Rs_b, Rp_b = np.abs(rs_b) ** 2, np.abs(rp_b) ** 2
    I_s = Rs_t + (1.0 - Rs_t) * Rs_b * (1.0 - Rs_b)
    I_p = Rp_t + (1.0 - Rp_t) * Rp_b * (1.0 - Rp_b)
    with np.errstate(invalid="ignore", divide="ignore"):
        dop = np.where(I_s + I_p > 0, (I_s - I_p) / (I_s + I_p), 0.0)
    return I_s, I_p, dop


def zenith_from_dop(dop_obs, I_s_obs, film_ior, substrate_ior, zenith_max_deg: float = 89.9):
    """The paper's Sec. 4.2: zenith from the DOP, branch by the s-intensity at Brewster.

    Returns
    -------
    zenith_deg : array like ``dop_obs``.
    brewster_deg : float
    """
    grid = np.linspace(0.0, zenith_max_deg, 4000)
    I_s, _, dop = incoherent_polarization_curve(film_ior, substrate_ior, grid)
    kb = int(np.argmax(dop))
    brewster = grid[kb]
    low = np.interp(dop_obs, dop[:kb + 1], grid[:kb + 1])               # rising branch
    high = np.interp(dop_obs, dop[kb:][::-1], grid[kb:][::-1])          # falling branch
    larger = I_s_obs > I_s[kb]
    return np.where(larger, high, low), brewster


def check_film_below_substrate(film, where="meta.json"):
    """Refuse a film whose index is not below its substrate's: the paper sets its method out
    for such films (Sec. 4, Figs. 4-5: 1.36 on 1.6; Sec. 6.3: "n2 is lower than that of the
    bottom layer")."""
    from thinfilm.core.errors import UserError

    n2, n3 = film.effective_index(), film.effective_substrate_index()
    if n2 >= n3:
        raise UserError(f"{where}: film index {n2:g} >= substrate index {n3:g}; the paper's method is set out for a "
                        f"film below its substrate's index (its Sec. 4, Figs. 4-5); the default method (coherent) "
                        f"handles both")


def reconstruct_kobayashi2023(capture: RGBCapture, progress: bool = False) -> Estimate:
    """The paper's polarized-RGB method as published (see the module docstring)."""
    check_film_below_substrate(capture.model.film)
    timings = {}
    t0 = time.perf_counter()
    mask = capture.mask
    stack = capture.stack()                      # (H, W, K, 3)
    angles = capture.angles_deg
    S0, S1, S2 = fit_stokes(np.moveaxis(stack, 2, 0), angles)   # (H, W, 3) each
    g0, g1, g2 = S0.mean(axis=-1), S1.mean(axis=-1), S2.mean(axis=-1)
    rho = dolp(g0, g1, g2)
    I_s_obs = s_polarized(g0, g1, g2)            # 2 I_max: the s-polarized reflectance
    film = capture.model.film
    zenith, brewster = zenith_from_dop(rho, I_s_obs, film.effective_index(), film.effective_substrate_index())
    phi_mod = azimuth_from_aolp_deg(aolp_deg(g1, g2))
    azimuth = resolve_azimuth(phi_mod, zenith, mask)
    timings["shape"] = time.perf_counter() - t0

    # Thickness: least squares against simulated RGB S0 over the range, at the pixel's zenith.
    t1 = time.perf_counter()
    lo, hi = capture.thickness_range_nm
    thick_grid = np.linspace(lo, hi, max(2, int(round(hi - lo)) + 1))   # 1 nm steps
    zen_step = 0.5
    rows = np.round(np.where(mask, zenith, 0.0) / zen_step).astype(int)
    thickness = np.zeros(mask.shape)
    used = np.unique(rows[mask])
    S0_tabs, _ = capture.model.rgb_s0_p(np.cos(np.radians(used * zen_step))[:, None], thick_grid[None, :])
    for r, S0_tab in progress_iter(zip(used, S0_tabs), "thickness table", progress, total=used.size):
        sel = mask & (rows == r)                                         # S0_tab: (D, 3)
        err = np.sum((S0[sel][:, None, :] - S0_tab[None, :, :]) ** 2, axis=-1)
        thickness[sel] = thick_grid[np.argmin(err, axis=1)]
    timings["thickness"] = time.perf_counter() - t1

    normals = angles_to_normals(zenith, np.nan_to_num(azimuth))
    valid = mask & np.isfinite(zenith) & np.isfinite(azimuth)
    from .rgb_capture import warn_if_outside_range

    warn_if_outside_range(capture, thickness, valid)
    info = {**capture.info, "brewster_angle_deg": float(brewster), "timings_s": timings,
            "notes": "paper Sec. 4 as published: incoherent DOP model (Eqs. 11-16), "
                     "boundary azimuth propagation, RGB table thickness search"}
    return Estimate(normals, thickness, valid, capture.info["film_ior"], capture.info["substrate_ior"],
                    None, capture.pixel_size, info)
