"""Otsu's threshold (thinfilm.core.masks) against its definition on the raw samples: the split
that minimises the within-class variance (Otsu 1979, equivalent to the largest between-class
variance of the histogram)."""

import numpy as np
import pytest

from thinfilm.core.masks import otsu_threshold


def _within_class_variance(values, t):
    lo, hi = values[values <= t], values[values > t]
    return lo.size * (lo.var() if lo.size else 0.0) + hi.size * (hi.var() if hi.size else 0.0)


@pytest.mark.parametrize("seed, fractions", [(0, (0.5, 0.5)), (1, (0.8, 0.2)), (2, (0.1, 0.9))])
def test_otsu_picks_the_split_of_least_within_class_variance(seed, fractions):
    rng = np.random.default_rng(seed)
    n = 4000
    values = np.r_[rng.normal(-2.0, 0.5, int(n * fractions[0])), rng.normal(1.5, 0.8, int(n * fractions[1]))]
    t = otsu_threshold(values)
    edges = np.histogram_bin_edges(values, bins=256)
    centers = 0.5 * (edges[:-1] + edges[1:])
    costs = np.array([_within_class_variance(values, c) for c in centers])
    # the best split over the bin centres, up to the samples that share t's bin
    assert _within_class_variance(values, t) <= costs.min() * (1 + 1e-3)
    assert -2.0 < t < 1.5


def test_reconstruction_masks_still_offers_the_one_otsu_threshold():
    from thinfilm.reconstruction import masks

    assert masks.otsu_threshold is otsu_threshold
