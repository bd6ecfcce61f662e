"""Camera noise model ``camera`` of the scene spec (``docs/design.md``, *Scene spec*, ``[noise]``).

Each image is exposed with a gain g (electrons per unit reflectance): ``exposure = "auto"``
picks g so that the image's brightest object pixel collects 90 % of the full well (as a
careful experimenter sets each band and each polarizer angle); a number fixes g. Then

- electrons  e = Poisson(g · x) + Normal(0, read_noise)          (shot and read noise)
- digital    DN = clip(round(e / full_well · (2^bits − 1)), 0, 2^bits − 1)   (quantization,
  saturation at the full well, no negative counts)
- stored     x' = DN · full_well / (2^bits − 1) / g              (reflectance units)

so the stored images keep the noise of the exposure they were taken at. Model ``none``
returns the exact images. Random numbers come from ``numpy.random.Generator`` objects
spawned in a fixed order from the spec's seed (one per image stack), so results are
reproducible.
"""

from __future__ import annotations

import numpy as np

__all__ = ["AUTO_EXPOSURE_FRACTION", "exposure_gains", "digitize", "apply_camera_noise"]

AUTO_EXPOSURE_FRACTION = 0.9


def exposure_gains(images: np.ndarray, mask: np.ndarray, noise: dict) -> np.ndarray:
    """Gain (electrons per unit reflectance) of each image in a stack.

    Parameters
    ----------
    images : array (N, H, W[, C])
        N images (an image may have colour channels, exposed together).
    mask : array (H, W) bool
        Object pixels (auto exposure looks only at them; the whole image if none).
    noise : dict
        ``full_well`` and ``exposure`` of the resolved spec.

    Returns
    -------
    ndarray (N,)
    """
    n = images.shape[0]
    if noise["exposure"] != "auto":
        return np.full(n, float(noise["exposure"]))
    sel = mask if np.any(mask) else np.ones(images.shape[1:3], dtype=bool)
    brightest = images[:, sel].reshape(n, -1).max(axis=1)
    target = AUTO_EXPOSURE_FRACTION * float(noise["full_well"])
    # A black image (nothing to expose for) gets the exposure of a perfect white reflector.
    return np.where(brightest > 0, target / np.where(brightest > 0, brightest, 1.0), target)


def digitize(images: np.ndarray, mask: np.ndarray, noise: dict, rng: np.random.Generator):
    """The camera's digital numbers of an image stack (model ``camera``): exposure, shot and
    read noise, quantization and clipping (see the module docstring).

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
