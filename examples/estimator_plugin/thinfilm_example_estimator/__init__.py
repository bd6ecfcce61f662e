"""An example third-party estimator for thinfilm: ``example-flat``.

It is a baseline, not a method: every object pixel gets the normal facing the camera and a
thickness in the middle of the prior range. It shows the whole estimator contract:

* the signature ``(dataset, options) -> Estimate`` (:mod:`thinfilm.core.registry`);
* the :func:`~thinfilm.core.registry.estimator` record (name, kind, the dataset parts it needs);
* the entry point of the group ``thinfilm.estimators`` in ``pyproject.toml``, which makes
  ``thinfilm methods``, ``thinfilm reconstruct rgb --method example-flat`` and
  ``thinfilm benchmark --methods example-flat`` find it once the package is installed.
"""

import numpy as np

from thinfilm.core.io import Estimate
from thinfilm.core.registry import estimator

__all__ = ["flat", "DEFAULT_RANGE_NM"]

#: prior thickness range (nm) when the command line gives none (--thickness-range)
DEFAULT_RANGE_NM = (100.0, 900.0)


@estimator("example-flat", kind="rgb", needs=("polarized_rgb",),
           description="example plugin: every normal facing the camera, thickness mid-range")
def flat(dataset, options):
    """Normals (0, 0, 1) and the mid-range thickness on the object's pixels."""
    if options.mask is not None:
        mask = np.asarray(options.mask, dtype=bool)
    else:  # the object is what reflects any light; the background is black
        mask = np.any([np.any(img > 0, axis=-1) for img in dataset.polarized_rgb.values()], axis=0)
    lo, hi = options.thickness_range_nm or DEFAULT_RANGE_NM
    normals = np.zeros(mask.shape + (3,))
    normals[..., 2] = 1.0
    return Estimate(normals=normals, thickness_nm=np.full(mask.shape, 0.5 * (lo + hi)), valid=mask,
                    film_ior=options.film.effective_index(),
                    substrate_ior=options.film.effective_substrate_index())
