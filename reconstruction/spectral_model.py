"""The spectral methods' view of the observation model: s (and p) spectra of pixels, with
derivatives, and misfits of candidate (angle, thickness, index) triples.

Every value comes from :class:`thinfilm.core.model.ObservationModel` (the optics core in a
Dr.Jit kernel, derivatives by forward-mode AD), for a single film of index ``n2`` on a
substrate ``n3``, seen at incidence ``θ`` in the plane of incidence of the Stokes reference
axis (``c2 = 1, s2 = 0``). What the capture holds, and so what is modelled:

* ``spectral_s``: ``S0 + sqrt(S1² + S2²)``, which is ``max(R_s, R_p)`` without noise and, with
  the per-pixel noise ``σ`` of the measured S1, S2, its expectation ``S0 + sqrt(P² + (π/2)
  σ²)`` (the mean of a Rice distribution, within 0.09 σ), which near normal incidence, where
  the light is barely polarized, sits above ``R_s``;
* the s and p spectra ``S0 ± P`` (a Stokes capture read along the plane of incidence).

``wavelengths_nm`` arguments take a band-centre array (point samples) or the dataset's
:class:`thinfilm.core.model.Rig`, whose passbands are then integrated where the fringes are
fast enough for it to matter (:func:`quadrature_for`).
"""

from __future__ import annotations

import functools

import numpy as np

from thinfilm.bsdf import optics
from thinfilm.core.model import ObservationModel, Observations, Rig

__all__ = [
    "PRECISION",
    "PASSBAND_DAMPING",
    "rig_of",
    "quadrature_for",
    "model_for",
    "rs_spectra",
    "grid_sse",
    "peak_reflectance",
    "angle_from_peak",
]

#: precision of the fits' kernels (single: about twice as fast on CPUs as double, and what
#: GPUs prefer; thickness resolution 1e-3 nm at 5 µm)
PRECISION = "single"
#: relative damping of the fringes by the passband from which the fits integrate it rather
#: than point-sample the band centres: ``1 - exp(-(a σ)² / 2)`` with ``a`` the film's largest
#: phase rate (rad/nm) over the bands and ``σ`` the passband's standard deviation. Below it
#: the point samples misstate the fringes by under 1 % of their amplitude (about 2e-4 of
#: reflectance for MgF2 on PET, under half the noise of one band at the default camera's full
#: well); at 4 nm FWHM from 400 nm it is reached at about 775 nm of a 1.37 film.
PASSBAND_DAMPING = 0.01
#: index of the model's film; a pixel's own index is an offset from it
_N2_REF = 1.0
_CHUNK = 1 << 22  # lanes × bands per kernel


def rig_of(wavelengths_nm) -> Rig:
    """A :class:`Rig` from a rig (returned as is) or band centres (point samples)."""
    if isinstance(wavelengths_nm, Rig):
        return wavelengths_nm
    return Rig(wavelengths_nm=tuple(np.asarray(wavelengths_nm, dtype=np.float64).ravel()))


def quadrature_for(rig: Rig, thickness_nm, film_ior) -> str:
    """``"passband"`` where point samples would misrepresent the fringes of the thickest film
    of ``thickness_nm`` (see :data:`PASSBAND_DAMPING`), else ``"centre"``."""
    if rig.band_fwhm_nm <= 0:
        return "centre"
    d = np.asarray(thickness_nm, dtype=np.float64)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return "centre"
    from thinfilm.core.bands import FWHM_TO_SIGMA

    n2 = float(np.max(np.asarray(film_ior, dtype=np.float64)))
    a = 4.0 * np.pi * n2 * float(np.max(d)) / min(rig.wavelengths_nm) ** 2
    sigma = rig.band_fwhm_nm * FWHM_TO_SIGMA
    return "passband" if 1.0 - np.exp(-0.5 * (a * sigma) ** 2) > PASSBAND_DAMPING else "centre"


@functools.lru_cache(maxsize=16)
def _model(rig: Rig, substrate_ior: float, quadrature: str) -> ObservationModel:
    from thinfilm.core.film import Film

    return ObservationModel(rig, Film.single(_N2_REF, None, substrate_ior), precision=PRECISION,
                            quadrature=quadrature)


def model_for(wavelengths_nm, substrate_ior, thickness_nm=None, film_ior=2.0) -> ObservationModel:
    """The observation model of a single film on ``substrate_ior`` seen through the bands of
    ``wavelengths_nm`` (a rig or band centres), its quadrature chosen for ``thickness_nm``
    (:func:`quadrature_for`; None: point samples)."""
    rig = rig_of(wavelengths_nm)
    q = "centre" if thickness_nm is None else quadrature_for(rig, thickness_nm, film_ior)
    return _model(rig, float(substrate_ior), q)


_JAC_COLUMN = {"theta": 0, "thickness": 1, "film_ior": 2}


def rs_spectra(theta_rad, thickness_nm, film_ior, substrate_ior, wavelengths_nm, jac=(),
               stokes_noise=None, with_p=False):
    """Measured s spectra of N pixels (see the module docstring) and, optionally, their
    partial derivatives (by AD).

    Parameters
    ----------
    theta_rad, thickness_nm : (N,) array_like
        Incident angle (radians) and film thickness (nm) per pixel.
    film_ior : float or (N,) array_like
        Film index n2 (one for all, or per pixel).
    substrate_ior : float
    wavelengths_nm : (B,) array_like or :class:`~thinfilm.core.model.Rig`
    jac : tuple of str
        Any of ``"theta"``, ``"thickness"``, ``"film_ior"``: derivatives to return.
    stokes_noise : (N,) array_like, optional
        Noise (standard deviation) of the measured S1 and S2 per pixel (the Rice bias).
    with_p : bool
        Every row holds the s spectrum followed by the p spectrum (2 B values;
        ``stokes_noise`` is then not used: both come from the linear Stokes parameters,
        which carry no such bias).

    Returns
    -------
    R : (N, B) or (N, 2 B) ndarray, followed by one array of the same shape per name in ``jac``.
    """
    theta = np.ascontiguousarray(theta_rad, dtype=np.float64).ravel()
    d = np.ascontiguousarray(thickness_nm, dtype=np.float64).ravel()
    n2 = np.broadcast_to(np.asarray(film_ior, dtype=np.float64), theta.shape).ravel()
    model = model_for(wavelengths_nm, substrate_ior, d, n2)
    b = len(model.rig.wavelengths_nm)
    x = np.stack([theta, d, n2 - _N2_REF], axis=1)
    fixed = {"c2": 1.0, "s2": 0.0}
    wrt = [_JAC_COLUMN[name] for name in jac]
    kind = "sp" if with_p else "spectral_s"
    noise = None if (stokes_noise is None or with_p) else np.broadcast_to(
        np.asarray(stokes_noise, dtype=np.float64), theta.shape)
    cols = 2 * b if with_p else b
    outs = [np.empty((theta.size, cols)) for _ in range(1 + len(jac))]
    rows = max(1, _CHUNK // cols)
    for s in range(0, theta.size, rows):
        e = min(theta.size, s + rows)
        got = model.evaluate(kind, x[s:e], "zenith", fixed, derivatives=bool(jac), wrt=wrt,
                             bias_sigma=None if noise is None else noise[s:e])
        if jac:
            values, J = got
            outs[0][s:e] = values
            for q in range(len(jac)):
                outs[1 + q][s:e] = J[:, :, q]
        else:
            outs[0][s:e] = got
    return outs[0] if not jac else tuple(outs)


def grid_sse(observed, theta_rad, thickness_nm, film_ior, substrate_ior, wavelengths_nm):
    """Sum over bands of squared residuals for K candidate (n2, d) pairs per pixel.

    Parameters
    ----------
    observed : (N, B) measured s spectra, or (N, 2 B) s then p spectra.
    theta_rad : (N,) incident angles.
    thickness_nm, film_ior : (N, K) candidates (NaN thickness: candidate skipped, SSE = inf).
    wavelengths_nm : (B,) array_like or :class:`~thinfilm.core.model.Rig`

    Returns
    -------
    (N, K) ndarray of ``Σ_λ (R_o(λ) - R_m(λ))²`` (Eq. 30 with the sum outside the square).
    """
    obs = np.asarray(observed, dtype=np.float64)
    theta = np.asarray(theta_rad, dtype=np.float64)
    d = np.asarray(thickness_nm, dtype=np.float64)
    n2 = np.asarray(film_ior, dtype=np.float64)
    n, k = d.shape
    bad = ~np.isfinite(d)
    d = np.where(bad, 0.0, d)
    model = model_for(wavelengths_nm, substrate_ior, d[~bad], n2)
    b = len(model.rig.wavelengths_nm)
    kind = "sp" if obs.shape[1] == 2 * b else "spectral_s"
    observations = Observations(kind, obs)
    x = np.stack([np.repeat(theta, k), d.ravel(), n2.ravel() - _N2_REF], axis=1)
    rows = np.repeat(np.arange(n), k)
    out = np.empty(n * k)
    per = max(1, _CHUNK // b)
    for s in range(0, n * k, per):
        e = min(n * k, s + per)
        _, _, out[s:e] = model.normal_equations(observations, x[s:e], "zenith", {"c2": 1.0, "s2": 0.0},
                                                rows=rows[s:e], derivatives=False)
    out = out.reshape(n, k)
    out[bad] = np.inf
    return out


def peak_reflectance(theta_rad, substrate_ior):
    """s reflectance at a constructive-interference peak (paper Eq. 21), from the optics core.

    At the peak ``e^{iΔ} = 1``; the Airy sum then no longer depends on the film, so this is the
    film reflectance evaluated at a thickness whose round-trip phase is ``Δ = 2π·0``.
    """
    theta = np.asarray(theta_rad, dtype=np.float64)
    return optics.reflectances(np.cos(theta), 550.0, 0.0, substrate_ior, substrate_ior)[0]


@functools.lru_cache(maxsize=8)
def _peak_table(substrate_ior):
    theta = np.radians(np.linspace(0.0, 89.99, 9000))
    return theta, peak_reflectance(theta, substrate_ior)


def angle_from_peak(peak_value, substrate_ior):
    """Invert Eq. 21 (monotone in θ): incident angle in radians from the peak reflectance.

    Values below the normal-incidence peak give 0; above the grazing value, 89.99°. NaN stays NaN.
    """
    theta, table = _peak_table(float(substrate_ior))
    v = np.asarray(peak_value, dtype=np.float64)
    out = np.interp(v, table, theta)
    return np.where(np.isnan(v), np.nan, out)
