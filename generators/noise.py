"""Camera noise drawn for the captures (scene spec ``[noise]``, ``docs/design.md``, *Scene spec*).

The model (exposure, shot and read noise, quantization, and the variance it gives each stored
value) is :mod:`thinfilm.core.noise`, defined there once; this module draws from it. Model
``none`` returns the exact images. Random numbers come from ``numpy.random.Generator`` objects
spawned in a fixed order from the spec's seed (one per image stack), so results are
reproducible.
"""

from __future__ import annotations

import numpy as np

from thinfilm.core.noise import AUTO_EXPOSURE_FRACTION, exposure_gains

__all__ = ["AUTO_EXPOSURE_FRACTION", "exposure_gains", "digitize", "apply_camera_noise"]


def digitize(images: np.ndarray, mask: np.ndarray, noise: dict, rng: np.random.Generator):
    """The camera's digital numbers of an image stack (model ``camera``): exposure, shot and
    read noise, quantization and clipping (:mod:`thinfilm.core.noise`).

    Parameters
    ----------
    images : array (N, H, W[, C]), reflectance units (or any signal proportional to the
        electrons collected), >= 0
    mask : array (H, W) bool
    noise : dict
        Resolved ``[noise]`` table.
    rng : numpy.random.Generator

    Returns
    -------
    dn : ndarray, same shape, float64 whole numbers in [0, 2^bits - 1]
    gains : ndarray (N,), electrons per unit of ``images``
    """
    images = np.asarray(images, dtype=np.float64)
    gains = exposure_gains(images, mask, noise)
    g = gains.reshape((-1,) + (1,) * (images.ndim - 1))
    full_well = float(noise["full_well"])
    levels = float(2 ** int(noise["bits"]) - 1)
    expected = np.clip(images, 0.0, None)
    expected *= g
    out = rng.poisson(expected).astype(np.float64)
    del expected
    if noise["read_noise"] > 0:
        out += rng.normal(0.0, float(noise["read_noise"]), size=images.shape)
    out *= levels / full_well
    np.rint(out, out=out)
    np.clip(out, 0.0, levels, out=out)
    return out, gains


def apply_camera_noise(images: np.ndarray, mask: np.ndarray, noise: dict,
                       rng: np.random.Generator) -> np.ndarray:
    """Noisy copy of an image stack (see the module docstring).

    Parameters
    ----------
    images : array (N, H, W[, C]), reflectance units, >= 0
    mask : array (H, W) bool
    noise : dict
        Resolved ``[noise]`` table.
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, same shape, float64
    """
    images = np.asarray(images, dtype=np.float64)
    if noise["model"] == "none":
        return images.copy()
    out, gains = digitize(images, mask, noise, rng)
    full_well = float(noise["full_well"])
    levels = float(2 ** int(noise["bits"]) - 1)
    out *= full_well / levels
    out /= gains.reshape((-1,) + (1,) * (images.ndim - 1))
    return out
