"""Input checks of the spectral methods: the cube, the object mask, the physics they assume.

The methods need a dielectric substrate (``k3 = 0``): the capture ``S0 + sqrt(S1² + S2²)`` is
``max(R_s, R_p)``, which is ``R_s`` for a film on a dielectric but not on an absorbing
substrate. The paper's peak analysis needs a film optically thinner than the substrate
(``n2 < n3``); :func:`check_peak_assumption` reads that from the physics of the spectra.
"""

from __future__ import annotations

import numpy as np

from thinfilm.core.errors import UserError

from .masks import mask_from_intensity
from .peaks import PEAK_NONE, PEAK_OK, PEAK_SEVERAL, find_peaks

__all__ = ["MIN_BANDS", "check_cube", "object_mask", "object_mask_stokes", "check_peak_assumption", "check_dielectric_substrate",
           "peaks_of"]

MIN_BANDS = 10


def check_cube(cube, wavelengths_nm, where="spectral_s"):
    """The cube (as given, a float array: NumPy converts pixels when they are used) and the
    wavelengths (float64), checked: shape, band count, increasing bands, finite values."""
    cube = np.asarray(cube)
    if not np.issubdtype(cube.dtype, np.floating):
        cube = cube.astype(np.float64)
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


def object_mask_stokes(stokes):
    """:func:`object_mask` of the s-polarized cube a Stokes cube gives (``S0 + |S1, S2|``,
    what a rotating-polarizer camera records as ``spectral_s``), from its band mean."""
    s0 = np.asarray(stokes["S0"])
    s = s0.mean(axis=2, dtype=np.float64) + np.hypot(stokes["S1"], stokes["S2"]).mean(axis=2, dtype=np.float64)
    return mask_from_intensity(s)


#: how many times better the minima's reading must fit for :func:`check_peak_assumption` to
#: refuse
DECISIVE = 4.0


def check_peak_assumption(spectra, wavelengths_nm, substrate_ior):
    """Raise :class:`UserError` when the spectra say ``n2 > n3`` (the paper's peaks are minima).

    Where the film's round-trip phase is a multiple of 2π the reflectance is the bare
    substrate's whatever the film (the paper's Eq. 21). With ``n2 < n3`` those are the
    maxima of the s spectrum (the constructive-interference peaks the paper reads), with
    ``n2 > n3`` the minima. Both readings are fitted to the object's spectra with one film
    index (:func:`.spectral_fit.estimate_film_ior_either_side`, on pixels at well-conditioned
    angles, whatever angles the object shows). Only a decisive verdict refuses: the minima's
    reading must explain the spectra :data:`DECISIVE` times better than the maxima's (a film
    above its substrate: 17-200 times better; a rough film, whose fringes the microfacets
    smear, can tilt the balance by a factor of 1.2-1.8 either way).

    Parameters
    ----------
    spectra : (N, B) object spectra (s).
    wavelengths_nm : (B,).
    substrate_ior : float.
    """
    from .spectral_fit import estimate_film_ior_either_side

    S = np.asarray(spectra, dtype=np.float64)
    if S.shape[0] < 20:
        return
    try:
        n2, info = estimate_film_ior_either_side(S, wavelengths_nm, substrate_ior, max_pixels=80)
    except UserError:
        return  # no extremum at all: the method itself reports what it cannot do
    below, above = info["film_ior_fit_below"], info["film_ior_fit_above"]
    decisive = below is None or (above is not None and above * DECISIVE < below)
    if info["film_ior_above_substrate"] and decisive:
        raise UserError(
            f"spectral_s: the spectra say the film index (about {n2:.2f}) is above the substrate's ({substrate_ior:g}): "
            f"their extrema at the bare substrate's reflectance are minima, so the constructive-interference peaks "
            f"the paper's method reads are not there; it needs n2 < n3 (the default method handles both; "
            f"check --substrate-ior)")


def check_dielectric_substrate(film, where):
    """Refuse an absorbing substrate (a :class:`thinfilm.core.film.Film`): the capture is then
    ``max(R_s, R_p)``, not ``R_s``."""
    if film.absorbing_substrate:
        k = float(np.max(film.substrate_n_k(np.linspace(300.0, 1000.0, 141))[1]))
        raise UserError(f"{where}: substrate_k = {k:g} (absorbing substrate); the spectral method "
                        f"assumes a dielectric substrate, where spectral_s = S0 + sqrt(S1² + S2²) is R_s "
                        f"(on an absorbing one it is max(R_s, R_p))")


def peaks_of(cube, mask, wl):
    """Object spectra, their peaks (:func:`.peaks.find_peaks`) and peak statistics."""
    spectra = cube[mask]
    pk = find_peaks(spectra, wl)
    stats = {
        "peak_one": int(np.sum(pk.status == PEAK_OK)),
        "peak_several": int(np.sum(pk.status == PEAK_SEVERAL)),
        "peak_none": int(np.sum(pk.status == PEAK_NONE)),
    }
    return spectra, pk, stats
