"""Reconstruction from s-polarized hyperspectral images, film index unknown (paper Sec. 6).

Input: ``spectral_s`` (H, W, B), the s reflectance per band, and the substrate index ``n3``.
Output: normals, film thickness per pixel and one film index ``n2`` for the object.

Methods (registered as ``reconstruct spectral --method NAME``, :mod:`.methods`):

``"kobayashi"`` (aliases ``"published"``, ``"paper"``) — the paper as published
    (:func:`.spectral_paper.reconstruct_kobayashi`).

``"stokes"`` — each pixel's s and p spectra fitted (the Stokes cube,
    :func:`.spectral_stokes.reconstruct_stokes`).

``"eikonal-s"`` — the s spectrum alone, solved at the object level
    (:func:`.spectral_eikonal.reconstruct_eikonal`).

``"auto"`` (the default; aliases ``"default"``, ``"eikonal"``) — ``stokes`` where the dataset
    holds the Stokes cube, else ``eikonal-s`` (:mod:`.methods`).

This module holds the array-level driver :func:`reconstruct_spectral` shared by all: input
checks (:mod:`.spectral_checks`), the object mask, timings and the height unit.

The substrate must be a dielectric (``k3 = 0``): the capture ``S0 + sqrt(S1² + S2²)`` is
``max(R_s, R_p)``, which is ``R_s`` for a film on a dielectric but not on an absorbing substrate,
so datasets with ``substrate_k > 0`` are refused. Heights (``surface.ply``) are in scene units
when the dataset's ``meta.json`` gives ``projection.pixel_size``, else in pixels.

The film must be optically thinner than the substrate (``n2 < n3``); otherwise the
constructive-interference extremum is a minimum and the method does not apply. Spectra that
never dip below the bare substrate's normal-incidence reflectance are reported as such.
"""

from __future__ import annotations

import time

import numpy as np

from thinfilm.core.errors import UserError
from thinfilm.core.io import Estimate

from .spectral_checks import check_cube, object_mask, object_mask_stokes
from .spectral_eikonal import reconstruct_eikonal

__all__ = ["reconstruct_spectral"]


def reconstruct_spectral(cube, wavelengths_nm, substrate_ior, mask=None, method=reconstruct_eikonal,
                         pixel_size=1.0, stokes=None, **method_options) -> Estimate:
    """Check a spectral capture and run a spectral method's pipeline on it.

    Parameters
    ----------
    cube : (H, W, B) s reflectance per band (None when ``stokes`` is given).
    wavelengths_nm : (B,) band centres.
    substrate_ior : float, the substrate index n3 (> 1).
    mask : (H, W) bool, optional; from the data (:func:`object_mask`) if not given.
    method : the pipeline, ``method(data, wavelengths_nm, substrate_ior, mask, **method_options)
        -> Estimate``: :func:`.spectral_eikonal.reconstruct_eikonal` or
        :func:`.spectral_paper.reconstruct_kobayashi` on the s cube,
        :func:`.spectral_stokes.reconstruct_stokes` on the Stokes cube.
    pixel_size : float
        Width of a pixel in scene units (``meta.json`` ``projection.pixel_size``): the height
        field, integrated from ``|∇z| = tan θ`` on the pixel grid, is scaled by it so that it
        is in the same unit as the pixel positions (1: both in pixels).
    stokes : dict ``S0``, ``S1``, ``S2`` → (H, W, B), optional
        The linear Stokes cube: when given, it is what ``method`` receives (a method of the
        Stokes capture), in place of ``cube``.
    method_options : passed to ``method`` (``thickness_range_nm``, ``band_fwhm_nm``, tuning).

    Returns
    -------
    :class:`thinfilm.core.io.Estimate` (``height`` in the unit of ``pixel_size``)
    """
    use_stokes = stokes is not None
    if use_stokes:
        for name in ("S0", "S1", "S2"):
            _, wl = check_cube(stokes[name], wavelengths_nm, where="stokes_spectral")
        shape = np.shape(stokes["S0"])[:2]
    else:
        cube, wl = check_cube(cube, wavelengths_nm)
        shape = cube.shape[:2]
    if not (substrate_ior > 1.0):
        raise UserError(f"expected an index above 1, got {substrate_ior}", argument="substrate_ior")
    if mask is None:
        mask = object_mask(cube) if not use_stokes else object_mask_stokes(stokes)
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != shape:
        raise UserError(f"shape {mask.shape} does not match the images {shape}", argument="mask")
    if mask.sum() < 20:
        raise UserError("spectral_s: fewer than 20 object pixels (nothing reflects above the background)")
    if not (np.isfinite(pixel_size) and pixel_size > 0):
        raise UserError(f"projection.pixel_size: expected a positive number, got {pixel_size}")
    t0 = time.perf_counter()
    est = method(stokes if use_stokes else cube, wl, float(substrate_ior), mask, **method_options)
    if est.height is not None:
        est.height = est.height * float(pixel_size)
    est.pixel_size = float(pixel_size)
    est.info["timings_s"]["total"] = time.perf_counter() - t0
    est.info["object_pixels"] = int(mask.sum())
    return est
