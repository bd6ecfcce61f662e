"""A complete estimator in one file: the object's silhouette as a hemisphere, the thickness
mid-range (a baseline any real method should beat).

Run it by its path, without installing anything (the module must be importable)::

    PYTHONPATH=examples .venv/bin/thinfilm reconstruct rgb data/cyl --method my_estimators:dome --out est/cyl-dome
"""

import numpy as np

from thinfilm.core.io import Estimate
from thinfilm.core.registry import estimator


@estimator("dome", kind="rgb", needs=("polarized_rgb",),
           description="the silhouette as a hemisphere, thickness mid-range")
def dome(dataset, options):
    mask = options.mask
    if mask is None:  # the object is what reflects light; the background is black
        mask = np.any([img.sum(axis=-1) > 0 for img in dataset.polarized_rgb.values()], axis=0)
    rows, cols = np.nonzero(mask)
    radius = max(np.ptp(rows), np.ptp(cols)) / 2 + 0.5
    y, x = np.mgrid[:mask.shape[0], :mask.shape[1]]
    nx, ny = (x - cols.mean()) / radius, (rows.mean() - y) / radius  # camera frame: x right, y up
    nz = np.sqrt(np.clip(1.0 - nx**2 - ny**2, 1e-4, None))
    normals = np.stack([nx, ny, nz], axis=-1)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    lo, hi = options.thickness_range_nm or (100.0, 900.0)
    return Estimate(normals, np.full(mask.shape, (lo + hi) / 2), mask,
                    film_ior=options.film.effective_index(),
                    substrate_ior=options.film.effective_substrate_index())
