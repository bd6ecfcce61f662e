"""The camera noise model of the captures (scene spec ``[noise]``, model ``camera``): how an
image of expected reflectance ``x`` is exposed, counted and stored, and the variance this
gives each stored value. The generator draws its noise from this model
(:mod:`thinfilm.generators.noise`); the Cramér-Rao bound (:mod:`thinfilm.core.bound`) uses its
variance.

Each image is exposed with a gain g (electrons per unit reflectance): ``exposure = "auto"``
picks g so that the image's brightest object pixel collects :data:`AUTO_EXPOSURE_FRACTION` of
the full well (as a careful experimenter sets each band and each polarizer angle; an image's
colour channels are exposed together); a number fixes g. Then

- electrons  e = Poisson(g · x) + Normal(0, read_noise)          (shot and read noise)
- digital    DN = clip(round(e / full_well · (2^bits − 1)), 0, 2^bits − 1)   (quantization,
  saturation at the full well, no negative counts)
- stored     x' = DN · full_well / (2^bits − 1) / g              (reflectance units)

so the stored values keep the noise of the exposure they were taken at. Below saturation
their variance is (:func:`capture_variance`)

    Var x' = (g x + read_noise²) / g² + Δ² / 12,    Δ = full_well / ((2^bits − 1) g),

shot noise, read noise and the quantization step's uniform rounding error. Model ``none``
stores the exact images (no variance).

Examples
--------
>>> noise = {"model": "camera", "full_well": 10000.0, "read_noise": 5.0, "bits": 12, "exposure": "auto"}
>>> img = np.array([[[0.2, 0.05]]])                       # one image of two pixels
>>> g = exposure_gains(img, np.ones((1, 2), bool), noise)
>>> float(g[0])                                          # 90 % of the full well at 0.2
45000.0
>>> v = capture_variance(img, g, noise)
>>> bool(np.allclose(v, (g[0] * img + 25.0) / g[0] ** 2 + (10000.0 / 4095 / g[0]) ** 2 / 12))
True
"""

from __future__ import annotations

import numpy as np

__all__ = ["AUTO_EXPOSURE_FRACTION", "exposure_gains", "capture_variance"]

#: share of the full well the brightest object pixel of an image collects under auto exposure
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


def capture_variance(images, gains, noise: dict) -> np.ndarray:
    """Variance of the stored values of images of expected reflectance ``images`` (N, ...)
    exposed with ``gains`` (N,), in reflectance units squared (the module docstring's
    formula; 0 for model ``none``)."""
    x = np.clip(np.asarray(images, dtype=np.float64), 0.0, None)
    if noise["model"] == "none":
        return np.zeros_like(x)
    g = np.asarray(gains, dtype=np.float64).reshape((-1,) + (1,) * (x.ndim - 1))
    step = float(noise["full_well"]) / float(2 ** int(noise["bits"]) - 1) / g
    return (g * x + float(noise["read_noise"]) ** 2) / (g * g) + step * step / 12.0
