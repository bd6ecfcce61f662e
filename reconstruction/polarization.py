"""Linear Stokes parameters from images behind a rotating linear polarizer.

Frame (``DESIGN.md``): the polarizer angle α is the angle of the transmission axis from
image +x towards image +y (y up), and the intensity behind it is

    I(α) = ½ (S0 + S1 cos 2α + S2 sin 2α),

so ``S1 = I(0°) - I(90°)`` and ``S2 = I(45°) - I(135°)``. Any three or more polarizer
angles that are distinct modulo 180° determine (S0, S1, S2); with more, the fit is the
least-squares one. Arrays follow the colour-science / polanalyser habit: any leading
shape, channels last.

For specular reflection off a surface of azimuth φ the reflected light is partially
polarized along the s-direction, φ + 90°: the angle of linear polarization (AoLP) of a
specular pixel is φ + 90° (mod 180°) wherever ``R_s > R_p``.

Examples
--------
>>> import numpy as np
>>> angles = [0, 45, 90, 135]
>>> I = malus_intensity(1.0, 0.3, -0.4, angles)          # analytic Malus-law values
>>> S0, S1, S2 = fit_stokes(np.stack(I, axis=0), angles)
>>> [round(float(v), 6) for v in (S0, S1, S2)]
[1.0, 0.3, -0.4]
>>> round(float(dolp(S0, S1, S2)), 6), round(float(aolp_deg(S1, S2)), 4)
(0.5, 153.4349)
"""

from __future__ import annotations

import numpy as np

from thinfilm.errors import UserError

__all__ = [
    "stokes_design_matrix",
    "check_polarizer_angles",
    "fit_stokes",
    "malus_intensity",
    "dolp",
    "aolp_deg",
    "stokes_from_dataset",
]


def stokes_design_matrix(angles_deg) -> np.ndarray:
    """The (K, 3) matrix A with ``I = A @ (S0, S1, S2)`` for polarizer angles in degrees."""
    a = np.radians(np.asarray(angles_deg, dtype=np.float64).ravel())
    return 0.5 * np.stack([np.ones_like(a), np.cos(2 * a), np.sin(2 * a)], axis=-1)


def check_polarizer_angles(angles_deg, where: str = "polarizer angles") -> np.ndarray:
    """Validate a list of polarizer angles: at least three distinct modulo 180°.

    Raises
    ------
    UserError
        Naming ``where`` (a file or option) when fewer than three distinct angles are given.
    """
    a = np.asarray(angles_deg, dtype=np.float64).ravel()
    distinct = np.unique(np.round(np.mod(a, 180.0), 6))
    if distinct.size < 3 or np.linalg.matrix_rank(stokes_design_matrix(distinct)) < 3:
        raise UserError(f"{where}: need images at >= 3 polarizer angles distinct modulo 180 deg "
                        f"to fit S0, S1, S2, got {a.tolist()}")
    return a


def fit_stokes(images, angles_deg):
    """Least-squares linear Stokes parameters from polarizer images.

    Parameters
    ----------
    images : array_like, shape (K, ...)
        Intensity behind the polarizer at each of the K angles (any trailing shape, e.g.
        (K, H, W, 3) for RGB images).
    angles_deg : sequence of K floats
        Polarizer transmission-axis angles, degrees from image +x towards +y.

    Returns
    -------
    S0, S1, S2 : ndarray, each of the trailing shape of ``images``.
    """
    angles = check_polarizer_angles(angles_deg)
    images = np.asarray(images, dtype=np.float64)
    if images.shape[0] != angles.size:
        raise ValueError(f"{images.shape[0]} images for {angles.size} polarizer angles")
    pinv = np.linalg.pinv(stokes_design_matrix(angles))  # (3, K)
    s = np.tensordot(pinv, images, axes=(1, 0))
    return s[0], s[1], s[2]


def malus_intensity(S0, S1, S2, angles_deg):
    """Intensity behind an ideal linear polarizer at each angle: list of arrays
    ``½ (S0 + S1 cos 2α + S2 sin 2α)``."""
    out = []
    for a in np.radians(np.asarray(angles_deg, dtype=np.float64).ravel()):
        out.append(0.5 * (np.asarray(S0) + np.asarray(S1) * np.cos(2 * a) + np.asarray(S2) * np.sin(2 * a)))
    return out


def dolp(S0, S1, S2):
    """Degree of linear polarization ``sqrt(S1² + S2²) / S0`` clipped to [0, 1] (0 where S0 <= 0).

    Equal to the paper's DOP ``(I_max - I_min) / (I_max + I_min)`` (its Eq. 10).
    """
    S0 = np.asarray(S0, dtype=np.float64)
    lin = np.hypot(S1, S2)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.where(S0 > 0, lin / np.where(S0 > 0, S0, 1.0), 0.0)
    return np.clip(rho, 0.0, 1.0)


def aolp_deg(S1, S2):
    """Angle of linear polarization ``½ atan2(S2, S1)`` in degrees, in [0, 180): the polarizer
    angle of maximum transmitted intensity."""
    return np.mod(0.5 * np.degrees(np.arctan2(S2, S1)), 180.0)


def stokes_from_dataset(polarized_rgb: dict, where: str = "polarized_rgb.exr"):
    """Stokes images (H, W, 3) each from a dataset's ``{angle: (H, W, 3)}`` polarizer images."""
    if not polarized_rgb:
        raise UserError(f"{where}: no polarizer layers (pol000, pol045, ...) found")
    angles = sorted(polarized_rgb)
    check_polarizer_angles(angles, where)
    return fit_stokes(np.stack([polarized_rgb[a] for a in angles], axis=0), angles)
