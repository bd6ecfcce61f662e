"""The project's conventions, written once: camera frame, zenith/azimuth, Stokes vectors.

Camera frame (``docs/design.md``, *Conventions*): image x to the right, y up, z towards the
camera; row 0 of an image is its top. Normals are unit vectors in this frame, ``n_z > 0`` where
visible. Zenith ``θ = arccos(n_z)``, azimuth ``φ = atan2(n_y, n_x)`` in [0, 360), both in
degrees in files.

Polarizer angle α: the angle of the transmission axis from image +x towards image +y. Stokes
vectors are in the same frame, and the intensity behind the polarizer is (Malus' law)

    I(α) = ½ (S0 + S1 cos 2α + S2 sin 2α),

so ``S1 = I(0°) - I(90°)`` and ``S2 = I(45°) - I(135°)``. Any three or more polarizer angles
that are distinct modulo 180° determine (S0, S1, S2); with more, the fit is the least-squares
one. Arrays follow the colour-science / polanalyser habit: any leading shape, channels last.

Specular reflection of unpolarized light off a surface of azimuth φ is partially polarized
along the s-direction φ + 90°: with ``S0 = (R_s + R_p)/2`` and ``P = (R_s - R_p)/2`` the
reflected Stokes vector is ``(S0, -P cos 2φ, -P sin 2φ)`` (:func:`specular_stokes`), so the
angle of linear polarization of a specular pixel is φ + 90° (mod 180°) wherever
``R_s > R_p``. A camera behind a rotating polarizer measures the s-polarized reflectance as
``S0 + sqrt(S1² + S2²)`` (:func:`s_polarized`), which is ``R_s`` on dielectric substrates.

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
>>> S = specular_stokes(0.06, 0.02, 30.0)                 # R_s, R_p, azimuth 30 deg
>>> round(float(aolp_deg(S[1], S[2])), 6)                 # the s-direction, 30 + 90
120.0
>>> round(float(s_polarized(*S)), 6)                      # R_s
0.06
"""

from __future__ import annotations

import numpy as np

from .errors import UserError

__all__ = [
    "normals_to_angles",
    "angles_to_normals",
    "stokes_design_matrix",
    "check_polarizer_angles",
    "fit_stokes",
    "analyzer_matrix",
    "malus_intensity",
    "specular_stokes",
    "s_polarized",
    "dolp",
    "aolp_deg",
    "azimuth_from_aolp_deg",
    "stokes_from_polarizer_images",
]


# -- normals and angles ---------------------------------------------------------------------

def normals_to_angles(normals):
    """Zenith θ = arccos(n_z) and azimuth φ = atan2(n_y, n_x) in [0, 360), both in degrees.

    The range holds in float32 too (files store float32): an azimuth a hair below 360 that
    would round up to 360.0 in float32 is returned as 0.

    Examples
    --------
    >>> z, a = normals_to_angles([0.0, -0.6, 0.8])
    >>> round(float(z), 4), round(float(a), 4)
    (36.8699, 270.0)
    """
    n = np.asarray(normals, dtype=np.float64)
    zenith = np.degrees(np.arccos(np.clip(n[..., 2], -1.0, 1.0)))
    azimuth = np.mod(np.degrees(np.arctan2(n[..., 1], n[..., 0])), 360.0)
    azimuth = np.where(azimuth.astype(np.float32) >= np.float32(360.0), 0.0, azimuth)
    return zenith, azimuth


def angles_to_normals(zenith_deg, azimuth_deg):
    """Unit normals (..., 3) from zenith and azimuth in degrees (the inverse of
    :func:`normals_to_angles`).

    Examples
    --------
    >>> np.round(angles_to_normals(90.0, 90.0), 6).tolist()
    [0.0, 1.0, 0.0]
    """
    t = np.radians(zenith_deg)
    p = np.radians(azimuth_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t) + 0.0 * p], axis=-1)


# -- Stokes vectors behind a rotating polarizer -----------------------------------------------

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
    if not np.all(np.isfinite(a)):
        raise UserError(f"{where}: polarizer angles must be finite numbers, got {a.tolist()}")
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


def analyzer_matrix(angles_deg, extinction_ratio=0.0, offset_deg=0.0) -> np.ndarray:
    """(K, 3) rows giving the intensity behind each of K real linear polarizers from the
    linear Stokes vector: ``½ (S0 + D (S1 cos 2θ + S2 sin 2θ))`` with ``θ = α + δ`` the
    polarizer's true axis (nominal angle α plus its measured offset δ, degrees) and ``D = (1 −
    ε) / (1 + ε)`` its diattenuation from its extinction ratio ε (minimum over maximum
    transmittance; 0: an ideal polarizer). Unpolarized light is transmitted ½, as by an ideal
    polarizer: the gains of a white target seen through the polarizers normalize the
    polarizer's mean transmittance away. ``extinction_ratio`` and ``offset_deg`` are numbers
    or one per angle. With ε = 0 and δ = 0 this is :func:`stokes_design_matrix`.

    >>> m = analyzer_matrix([0, 45, 90, 135], 0.1, 2.0)
    >>> bool(np.allclose(m[:, 0], 0.5)), round(float(np.hypot(m[0, 1], m[0, 2])), 6)
    (True, 0.409091)
    """
    a = np.radians(np.asarray(angles_deg, dtype=np.float64).ravel() + np.asarray(offset_deg, dtype=np.float64))
    eps = np.broadcast_to(np.asarray(extinction_ratio, dtype=np.float64), a.shape)
    d = (1.0 - eps) / (1.0 + eps)
    return 0.5 * np.stack([np.ones_like(a), d * np.cos(2 * a), d * np.sin(2 * a)], axis=-1)


def malus_intensity(S0, S1, S2, angles_deg):
    """Intensity behind an ideal linear polarizer at each angle: a list of arrays
    ``½ (S0 + S1 cos 2α + S2 sin 2α)``."""
    out = []
    for a in np.radians(np.asarray(angles_deg, dtype=np.float64).ravel()):
        out.append(0.5 * (np.asarray(S0) + np.asarray(S1) * np.cos(2 * a) + np.asarray(S2) * np.sin(2 * a)))
    return out


def specular_stokes(R_s, R_p, azimuth_deg):
    """Stokes vector ``(S0, S1, S2)`` of unpolarized unit light reflected specularly by a
    surface of azimuth φ with power reflectances ``R_s``, ``R_p``:
    ``(S0, -P cos 2φ, -P sin 2φ)`` with ``S0 = (R_s + R_p)/2``, ``P = (R_s - R_p)/2``.

    ``R_s``, ``R_p`` may carry trailing channel or band axes; ``azimuth_deg`` then needs
    matching leading axes (it is broadcast against ``R_s[..., None]`` when their dimensions
    differ by one).
    """
    R_s = np.asarray(R_s, dtype=np.float64)
    R_p = np.asarray(R_p, dtype=np.float64)
    phi2 = 2.0 * np.radians(np.asarray(azimuth_deg, dtype=np.float64))
    if phi2.ndim and phi2.ndim == R_s.ndim - 1:
        phi2 = phi2[..., None]
    S0 = 0.5 * (R_s + R_p)
    P = 0.5 * (R_s - R_p)
    return S0, -P * np.cos(phi2), -P * np.sin(phi2)


def s_polarized(S0, S1, S2):
    """What a camera behind a rotating polarizer reports as the s-polarized reflectance:
    ``S0 + sqrt(S1² + S2²)`` (the maximum over polarizer angles, doubled)."""
    return np.asarray(S0) + np.hypot(S1, S2)


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


def azimuth_from_aolp_deg(aolp):
    """Surface azimuth modulo 180° (in [0, 180)) of a specular pixel from its angle of linear
    polarization: the s-direction is φ + 90°."""
    return np.mod(np.asarray(aolp, dtype=np.float64) - 90.0, 180.0)


def stokes_from_polarizer_images(images: dict, where: str = "polarized_rgb.exr"):
    """Stokes images from ``{angle_deg: image}`` polarizer images (any common shape, e.g.
    (H, W, 3)), by :func:`fit_stokes`; ``where`` names the source in errors."""
    if not images:
        raise UserError(f"{where}: no polarizer layers (pol000, pol045, ...) found")
    angles = sorted(images)
    check_polarizer_angles(angles, where)
    return fit_stokes(np.stack([images[a] for a in angles], axis=0), angles)
