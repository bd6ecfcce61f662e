"""Helpers for the generator tests: small datasets, independent tmm references."""

from __future__ import annotations

import math

import numpy as np

def small_spec(preset, resolution=32, noise="none", seed=0, extra=()):
    from thinfilm.generators.spec import load_spec

    return load_spec(preset, overrides=[f"noise.model={noise}", *extra], resolution=resolution, seed=seed)


def make_dataset(tmp_path_factory, name, spec):
    from thinfilm.core.io import read_dataset
    from thinfilm.generators.generate import generate_dataset

    out = tmp_path_factory.mktemp("gen") / name
    generate_dataset(spec, out, progress=False)
    return read_dataset(out, need=("ground_truth", "polarized_rgb", "spectral_s", "stokes"))


def tmm_rs_rp(zenith_deg, wavelength_nm, thickness_nm, n_film, n_sub, k_sub=0.0):
    """R_s, R_p of air | film | substrate (index ``n_sub + i k_sub``) from the ``tmm`` package
    (independent reference)."""
    import tmm

    th = math.radians(float(zenith_deg))
    sub = complex(float(n_sub), float(k_sub)) if k_sub else float(n_sub)
    nl, dl = [1.0, float(n_film), sub], [np.inf, float(thickness_nm), np.inf]
    return (tmm.coh_tmm("s", nl, dl, th, float(wavelength_nm))["R"],
            tmm.coh_tmm("p", nl, dl, th, float(wavelength_nm))["R"])


def tmm_band(zenith_deg, centre_nm, fwhm_nm, thickness_nm, n_film, n_sub, pol="s", dense_nm=0.1, k_sub=0.0):
    """Gaussian-passband average of tmm's R (dense Riemann sum over ±6 sigma)."""
    sigma = fwhm_nm / (2 * math.sqrt(2 * math.log(2)))
    lam = centre_nm + np.arange(-6 * sigma, 6 * sigma + dense_nm / 2, dense_nm)
    w = np.exp(-0.5 * ((lam - centre_nm) / sigma) ** 2)
    idx = 0 if pol == "s" else 1
    r = np.array([tmm_rs_rp(zenith_deg, x, thickness_nm, n_film, n_sub, k_sub)[idx] for x in lam])
    return float(np.sum(w * r) / np.sum(w))


def pixel_centres(meta, shape):
    """World (x, y) at pixel centres from a dataset's ``projection`` entry."""
    x0, x1, y0, y1 = meta["projection"]["image_extent"]
    h, w = shape
    xs = x0 + (np.arange(w) + 0.5) * (x1 - x0) / w
    ys = y1 - (np.arange(h) + 0.5) * (y1 - y0) / h
    return np.meshgrid(xs, ys)


def interior_pixels(mask, count, seed=0):
    """``count`` deterministic pixels of ``mask`` away from its border (3x3 erosion)."""
    from scipy.ndimage import binary_erosion

    inner = binary_erosion(mask, iterations=1)
    rows, cols = np.nonzero(inner)
    rng = np.random.default_rng(seed)
    pick = rng.choice(rows.size, size=min(count, rows.size), replace=False)
    return rows[pick], cols[pick]
