"""An analytic dataset folder for the evaluation tests, written without Mitsuba.

Captures come straight from the optics core (``thinfilm.bsdf.optics.reflectances``, checked
against ``tmm``) on an analytic hemisphere normal field, so the re-rendering (Mitsuba, the
plugin, the normal-mapped plane) is compared with an independent prediction.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from thinfilm.bsdf import optics
from thinfilm.core.colorimetry import spectra_to_camera_rgb
from thinfilm.core.conventions import malus_intensity
from thinfilm.core.film import Film
from thinfilm.core.io import dataset_meta, write_dataset

__all__ = ["hemisphere_normals", "analytic_stokes", "write_synthetic_dataset"]


def hemisphere_normals(size: int, fill: float = 0.9):
    """Normals (size, size, 3) and mask of a hemisphere seen from above (pixel centres)."""
    c = (np.arange(size) + 0.5 - size / 2) / (size / 2 * fill)
    x, y = np.meshgrid(c, -c)  # row 0 = top = +y
    r2 = x ** 2 + y ** 2
    mask = r2 < 1.0
    z = np.sqrt(np.clip(1.0 - r2, 0.0, None))
    n = np.stack([x, y, z], axis=-1)
    n[~mask] = (0.0, 0.0, 1.0)
    return n, mask


def analytic_stokes(normals, mask, thickness_nm, wavelengths_nm, film_ior, substrate_ior):
    """Stokes cube of specular reflection of a unit unpolarized dome: S0 = (Rs + Rp)/2 and
    S1, S2 = −(Rs − Rp)/2 (cos 2φ, sin 2φ) (intensity peaks at α = φ + 90°, the s-direction)."""
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    rs, rp = optics.reflectances(normals[..., 2:3], wl, np.asarray(thickness_nm)[..., None],
                                 film_ior, substrate_ior)
    phi = np.arctan2(normals[..., 1], normals[..., 0])[..., None]
    m = mask[..., None]
    s0 = np.where(m, 0.5 * (rs + rp), 0.0)
    d = np.where(m, 0.5 * (rs - rp), 0.0)
    return {"S0": s0, "S1": -d * np.cos(2 * phi), "S2": -d * np.sin(2 * phi)}


def write_synthetic_dataset(root, size=24, wavelengths_nm=None, film_ior=1.37, substrate_ior=1.6,
                            thickness_nm=None, parts=("polarized_rgb", "spectral_s", "stokes"),
                            camera="Nikon 5100 (NPL)", illuminant="D65"):
    """Write a noise-free ``thinfilm-dataset/1`` folder of a hemisphere (point-sampled bands,
    ``band_fwhm_nm = 0``); returns
    ``(root, normals, mask, thickness_nm, stokes)``."""
    root = Path(root)
    root.mkdir(parents=True)
    wl = np.arange(400.0, 721.0, 16.0) if wavelengths_nm is None else np.asarray(wavelengths_nm, float)
    n, mask = hemisphere_normals(size)
    if thickness_nm is None:
        thickness_nm = 450.0 + 120.0 * n[..., 0]
    thickness_nm = np.where(mask, thickness_nm, 0.0)
    stokes = analytic_stokes(n, mask, thickness_nm, wl, film_ior, substrate_ior)
    zenith = np.degrees(np.arccos(n[..., 2]))
    azimuth = np.degrees(np.arctan2(n[..., 1], n[..., 0])) % 360.0
    angles = [0, 45, 90, 135]
    gt = {"normal": n, "zenith": zenith, "azimuth": azimuth, "thickness": thickness_nm, "depth": n[..., 2],
          "mask": mask}
    meta = dataset_meta(wavelengths_nm=wl.tolist(), band_fwhm_nm=0.0, passband="gaussian",
                        polarizer_angles_deg=angles, camera=camera, illuminant=illuminant,
                        **Film.single(film_ior, None, substrate_ior).to_meta(),
                        seed=0, noise={"model": "none"})
    polarized = None
    if "polarized_rgb" in parts:
        images = malus_intensity(stokes["S0"], stokes["S1"], stokes["S2"], angles)
        polarized = {a: spectra_to_camera_rgb(img, wl, camera, illuminant) for a, img in zip(angles, images)}
    spectral = None
    if "spectral_s" in parts:
        spectral = stokes["S0"] + np.sqrt(stokes["S1"] ** 2 + stokes["S2"] ** 2)
    write_dataset(root, meta, ground_truth=gt, polarized_rgb=polarized, spectral_s=spectral,
                  stokes=stokes if "stokes" in parts else None, preview=False)
    return root, n, mask, thickness_nm, stokes
