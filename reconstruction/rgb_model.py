"""Forward model of polarized camera RGB for a thin film seen in specular reflection.

A pixel whose surface normal has zenith θ and azimuth φ (camera frame of ``DESIGN.md``)
reflects the uniform, unpolarized dome towards the orthographic camera at incidence θ.
Per band the reflected Stokes vector is, in the image frame,

    S0 = (R_s + R_p) / 2,   S1 = -P cos 2φ,   S2 = -P sin 2φ,   P = (R_s - R_p) / 2,

because the s-direction (perpendicular to the plane of incidence) lies at φ + 90° in the
image. ``R_s``, ``R_p`` come from :mod:`thinfilm.bsdf.optics` (the coherent Airy model, the
project's one copy of the physics) and the camera response from
:func:`thinfilm.colorimetry.camera_weights` (the same white-balanced weights the capture
generator uses). Behind a polarizer at α the camera sees
``½ (S0 + S1 cos 2α + S2 sin 2α)`` per RGB channel.

Zenith is carried as ``u = sin² θ`` inside the solvers: the polarization signal grows
linearly in ``u`` near normal incidence, which keeps the inversion well conditioned there.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from thinfilm.bsdf import optics
from thinfilm.bsdf.materials import as_dispersion
from thinfilm.colorimetry import DEFAULT_CAMERA, DEFAULT_ILLUMINANT, camera_weights

__all__ = ["FilmCamera"]


@dataclass
class FilmCamera:
    """A film (index n2, possibly dispersive) on a substrate n3, seen by an RGB camera.

    Parameters
    ----------
    wavelengths_nm : (B,) band centres.
    film_ior : number, material name or dispersion model (:func:`~thinfilm.bsdf.materials.as_dispersion`).
    substrate_ior : number (real index n3; ``substrate_k`` for absorbing substrates).
    camera, illuminant : names or CSV paths, as in :mod:`thinfilm.colorimetry`.
    """

    wavelengths_nm: np.ndarray
    film_ior: object = 1.37
    substrate_ior: object = 1.6
    substrate_k: float = 0.0
    camera: str = DEFAULT_CAMERA
    illuminant: str = DEFAULT_ILLUMINANT
    weights: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        self.wavelengths_nm = np.asarray(self.wavelengths_nm, dtype=np.float64)
        self.weights = camera_weights(self.wavelengths_nm, self.camera, self.illuminant)  # (B, 3)
        self._n2 = np.asarray(as_dispersion(self.film_ior)(self.wavelengths_nm), dtype=np.float64)
        self._n3 = np.asarray(as_dispersion(self.substrate_ior)(self.wavelengths_nm), dtype=np.float64)

    # -- spectra ------------------------------------------------------------------------
    def spectra(self, cos_theta, thickness_nm):
        """Spectral ``(S0, P)``, each of shape ``broadcast(cos_theta, thickness_nm) + (B,)``,
        with ``S0 = (R_s + R_p)/2`` and ``P = (R_s - R_p)/2``."""
        c = np.asarray(cos_theta, dtype=np.float64)[..., None]
        d = np.asarray(thickness_nm, dtype=np.float64)[..., None]
        Rs, Rp = optics.reflectances(c, self.wavelengths_nm, d, self._n2, self._n3, self.substrate_k)
        return 0.5 * (Rs + Rp), 0.5 * (Rs - Rp)

    def rgb_s0_p(self, cos_theta, thickness_nm, chunk: int = 65536):
        """Camera-RGB ``(S0, P)``, each ``shape + (3,)`` (the band axis integrated out)."""
        c, d = np.broadcast_arrays(np.asarray(cos_theta, dtype=np.float64),
                                   np.asarray(thickness_nm, dtype=np.float64))
        shape = c.shape
        c, d = c.ravel(), d.ravel()
        S0 = np.empty((c.size, 3))
        P = np.empty((c.size, 3))
        for i in range(0, c.size, chunk):
            s0, p = self.spectra(c[i:i + chunk], d[i:i + chunk])
            S0[i:i + chunk] = s0 @ self.weights
            P[i:i + chunk] = p @ self.weights
        return S0.reshape(shape + (3,)), P.reshape(shape + (3,))

    def rgb_stokes(self, zenith_deg, azimuth_deg, thickness_nm):
        """Camera-RGB Stokes ``(S0, S1, S2)`` in the image frame, each ``shape + (3,)``."""
        S0, P = self.rgb_s0_p(np.cos(np.radians(zenith_deg)), thickness_nm)
        phi2 = 2.0 * np.radians(np.asarray(azimuth_deg, dtype=np.float64))[..., None]
        return S0, -P * np.cos(phi2), -P * np.sin(phi2)

    def polarized_rgb(self, zenith_deg, azimuth_deg, thickness_nm, angles_deg):
        """Noise-free camera RGB behind the polarizer at each angle: ``{angle: shape + (3,)}``."""
        S0, S1, S2 = self.rgb_stokes(zenith_deg, azimuth_deg, thickness_nm)
        out = {}
        for a in angles_deg:
            t = np.radians(a)
            out[a] = 0.5 * (S0 + S1 * np.cos(2 * t) + S2 * np.sin(2 * t))
        return out
