"""CIELAB from reflectance spectra or camera RGB, and colour differences ΔE*ab / ΔE00.

Spectra are converted with the CIE 1931 2° standard observer under the dataset's
illuminant, relative to the perfect reflecting diffuser (reflectance 1 at every band,
``Y_n = 100``), as in CIE 15:

.. math::

    X = k \\sum_\\lambda R(\\lambda) E(\\lambda) \\bar x(\\lambda) \\Delta\\lambda, \\quad
    k = 100 / \\sum_\\lambda E(\\lambda) \\bar y(\\lambda) \\Delta\\lambda .

``Δλ`` are the trapezoid weights of the band grid
(:func:`thinfilm.core.colorimetry.band_widths`) and the illuminant comes from
:func:`thinfilm.core.colorimetry.illuminant_spd`: the same quadrature and light as camera RGB,
so a camera that satisfies the Luther condition gives exactly these XYZ. CIELAB (``colour.XYZ_to_Lab``) and the colour
differences (``colour.delta_E``, methods ``"CIE 1976"`` — the paper's Eq. 31 — and
``"CIE 2000"``) come from colour-science.

Captures that hold only camera RGB are taken to XYZ by a 3×3 matrix fitted from the
camera's sensitivities (:func:`fit_camera_to_xyz`): the least-squares fit of the
illuminant-weighted CIE 1931 colour-matching functions by linear combinations of the
illuminant-weighted, white-balanced camera sensitivities over the band grid (a
Luther–Ives fit), constrained so that camera white ``(1, 1, 1)`` maps exactly to the
perfect white's XYZ. It is exact only for a camera that satisfies the Luther condition;
for the Nikon 5100 it is an approximation and ΔE computed from RGB is less precise than
ΔE computed from spectra.

Examples
--------
>>> import numpy as np
>>> wl = np.arange(400.0, 721.0, 4.0)
>>> np.round(spectra_to_lab(np.ones(wl.shape), wl), 6).tolist() == [100.0, 0.0, 0.0]
True
"""

from __future__ import annotations

import functools

import numpy as np

from thinfilm.core.colorimetry import DEFAULT_CAMERA, DEFAULT_ILLUMINANT, band_widths, camera_weights, illuminant_spd
from thinfilm.core.errors import UserError

__all__ = [
    "OBSERVER",
    "cie1931_cmfs",
    "xyz_weights",
    "spectra_to_xyz",
    "white_xyz",
    "xyz_to_lab",
    "spectra_to_lab",
    "fit_camera_to_xyz",
    "camera_rgb_to_lab",
    "delta_e_ab",
    "delta_e_2000",
]

OBSERVER = "CIE 1931 2 Degree Standard Observer"


def cie1931_cmfs(wavelengths_nm) -> np.ndarray:
    """CIE 1931 2° colour-matching functions x̄, ȳ, z̄ at ``wavelengths_nm``, shape (B, 3).

    Linear interpolation in colour-science's 1 nm table (exact at whole nanometres), zero
    outside 360–830 nm.
    """
    import colour

    cmfs = colour.MSDS_CMFS[OBSERVER]
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    table = np.asarray(cmfs.values, dtype=np.float64)
    grid = np.asarray(cmfs.wavelengths, dtype=np.float64)
    return np.stack([np.interp(wl, grid, table[:, c], left=0.0, right=0.0) for c in range(3)], axis=-1)


@functools.lru_cache(maxsize=16)
def _xyz_weights_cached(wl_key: tuple, illuminant: str) -> np.ndarray:
    wl = np.asarray(wl_key, dtype=np.float64)
    e = illuminant_spd(illuminant, wl) * band_widths(wl)
    w = cie1931_cmfs(wl) * e[:, None]
    norm = w[:, 1].sum()
    if norm <= 0:
        raise UserError(f"illuminant {illuminant!r} gives no luminance over "
                        f"{wl[0]:.0f}-{wl[-1]:.0f} nm")
    w = w * (100.0 / norm)
    w.setflags(write=False)
    return w


def xyz_weights(wavelengths_nm, illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
    """Weights W (B, 3) with ``XYZ = R @ W`` (``Y = 100`` for the perfect white)."""
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    if wl.ndim != 1 or wl.size < 2 or np.any(np.diff(wl) <= 0):
        raise UserError(f"wavelengths_nm must be increasing with at least 2 entries, got {wl.tolist()}")
    return _xyz_weights_cached(tuple(wl.tolist()), str(illuminant))


def spectra_to_xyz(reflectance, wavelengths_nm, illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
    """CIE 1931 XYZ (0–100 scale) of reflectance spectra, shape (..., B) → (..., 3)."""
    return np.asarray(reflectance, dtype=np.float64) @ xyz_weights(wavelengths_nm, illuminant)


def white_xyz(wavelengths_nm, illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
    """XYZ of the perfect reflecting diffuser (R = 1) on the band grid; ``Y = 100``."""
    return xyz_weights(wavelengths_nm, illuminant).sum(axis=0)


def xyz_to_lab(xyz, xyz_white) -> np.ndarray:
    """CIELAB of XYZ (0–100 scale) relative to the white ``xyz_white`` (``colour.XYZ_to_Lab``)."""
    import colour

    white = np.asarray(xyz_white, dtype=np.float64)
    xy_white = colour.XYZ_to_xy(white / white[1])
    return np.asarray(colour.XYZ_to_Lab(np.asarray(xyz, dtype=np.float64) / white[1], xy_white),
                      dtype=np.float64)


def spectra_to_lab(reflectance, wavelengths_nm, illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
    """CIELAB (..., 3) of reflectance spectra (..., B): CIE 1931 2°, ``illuminant``,
    perfect-white reference."""
    return xyz_to_lab(spectra_to_xyz(reflectance, wavelengths_nm, illuminant),
                      white_xyz(wavelengths_nm, illuminant))


def fit_camera_to_xyz(wavelengths_nm, camera: str = DEFAULT_CAMERA,
                      illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
    """3×3 matrix M with ``XYZ ≈ rgb @ M`` for white-balanced camera RGB.

    Least squares ``min ‖C M − X‖²`` over the band grid, where the rows of C are the
    camera's white-balanced band weights (:func:`thinfilm.core.colorimetry.camera_weights`) and
    the rows of X the XYZ band weights (:func:`xyz_weights`), subject to
    ``(1, 1, 1) M = XYZ_white`` so that white is reproduced exactly. Solved per column
    through the KKT system.

    Returns
    -------
    ndarray, shape (3, 3)
    """
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    c = camera_weights(wl, camera, illuminant)     # (B, 3), columns sum to 1
    x = xyz_weights(wl, illuminant)                 # (B, 3), column sums = white XYZ
    white = x.sum(axis=0)
    ones = np.ones(3)
    kkt = np.zeros((4, 4))
    kkt[:3, :3] = 2.0 * c.T @ c
    kkt[:3, 3] = ones
    kkt[3, :3] = ones
    m = np.zeros((3, 3))
    for j in range(3):
        rhs = np.concatenate([2.0 * c.T @ x[:, j], [white[j]]])
        m[:, j] = np.linalg.solve(kkt, rhs)[:3]
    return m


def camera_rgb_to_lab(rgb, wavelengths_nm, camera: str = DEFAULT_CAMERA,
                      illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
    """CIELAB (..., 3) of white-balanced camera RGB (..., 3) through :func:`fit_camera_to_xyz`."""
    m = fit_camera_to_xyz(wavelengths_nm, camera, illuminant)
    return xyz_to_lab(np.asarray(rgb, dtype=np.float64) @ m, white_xyz(wavelengths_nm, illuminant))


def delta_e_ab(lab_a, lab_b) -> np.ndarray:
    """CIE 1976 colour difference ΔE*ab (paper Eq. 31), ``colour.delta_E(method="CIE 1976")``."""
    import colour

    return np.asarray(colour.delta_E(np.asarray(lab_a, dtype=np.float64),
                                     np.asarray(lab_b, dtype=np.float64), method="CIE 1976"))


def delta_e_2000(lab_a, lab_b) -> np.ndarray:
    """CIEDE2000 colour difference ΔE00, ``colour.delta_E(method="CIE 2000")``."""
    import colour

    return np.asarray(colour.delta_E(np.asarray(lab_a, dtype=np.float64),
                                     np.asarray(lab_b, dtype=np.float64), method="CIE 2000"))
