"""The estimates' uncertainty (``normal_sigma_deg``, ``thickness_sigma_nm``): the formulas
against Monte Carlo and ``tmm``, and the calibration of the defaults' σ on rendered scenes."""

from __future__ import annotations

import math
import shutil
import warnings

import numpy as np
import pytest

from thinfilm.core.bound import angle_sigma_deg, image_plane_jacobian, normal_jacobian


def _rms_angle(n_true, n_samples):
    cos = np.clip(n_samples @ n_true, -1.0, 1.0)
    return float(np.degrees(np.sqrt(np.mean(np.arccos(cos) ** 2))))


def test_the_normal_sigma_is_the_rms_angle_of_a_perturbed_normal():
    """``angle_sigma_deg`` of both parametrizations (image-plane (a, b) and the double angle
    ``v``) against the RMS angle of normals drawn with the stated covariance."""
    rng = np.random.default_rng(5)
    for theta, phi in ((0.3, 0.4), (0.9, 2.5), (1.2, -1.0)):
        n = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
        L = rng.normal(size=(2, 2)) * 2e-3
        cov = L @ L.T + np.eye(2) * 1e-6
        draws = rng.multivariate_normal(np.zeros(2), cov, size=200_000)
        ab = n[:2] + draws
        samples = np.concatenate([ab, np.sqrt(1 - np.sum(ab ** 2, axis=1))[:, None]], axis=1)
        want = _rms_angle(n, samples)
        got = angle_sigma_deg(image_plane_jacobian(n[None, :2]), cov[None])[0]
        assert got == pytest.approx(want, rel=0.02)
        u = np.sin(theta) ** 2
        v = np.array([u * np.cos(2 * phi), u * np.sin(2 * phi)])
        vs = v + draws
        us = np.hypot(vs[:, 0], vs[:, 1])
        ps = 0.5 * np.arctan2(vs[:, 1], vs[:, 0])
        ps = np.where(np.cos(ps - phi) < 0, ps + np.pi, ps)
        samples = np.stack([np.sqrt(us) * np.cos(ps), np.sqrt(us) * np.sin(ps), np.sqrt(1 - us)], axis=1)
        got = angle_sigma_deg(normal_jacobian(v[None]), cov[None])[0]
        assert got == pytest.approx(_rms_angle(n, samples), rel=0.02)


def test_the_thickness_an_index_error_carries_is_the_fringes():
    """``index_thickness_sigma``: a film whose index is off by δ puts a reflectance minimum (tmm)
    at the same wavelength only at another thickness; the shift per δ is the formula's."""
    from scipy.optimize import brentq, minimize_scalar

    from thinfilm.reconstruction.spectral_fit import index_thickness_sigma
    from tests._gen_fixtures import tmm_rs_rp

    def minimum_nm(d, n2, theta_deg, around):
        r = minimize_scalar(lambda lam: tmm_rs_rp(theta_deg, lam, d, n2, 1.6)[0], bounds=(around - 25, around + 25),
                            method="bounded", options={"xatol": 1e-7})
        return r.x

    for d, n2, theta_deg in ((380.0, 1.38, 20.0), (700.0, 1.46, 55.0)):
        # the minimum of order m: 2 d sqrt(n2² - sin² θ) = (m + 1/2) λ
        path = 2 * d * math.sqrt(n2 ** 2 - math.sin(math.radians(theta_deg)) ** 2)
        guess = path / (round(path / 560.0 - 0.5) + 0.5)
        lam = minimum_nm(d, n2, theta_deg, guess)
        delta = 1e-3
        d2 = brentq(lambda x: minimum_nm(x, n2 + delta, theta_deg, lam) - lam, d - 5.0, d + 5.0, xtol=1e-7)
        slope = abs(d2 - d) / delta
        got = index_thickness_sigma(d, math.radians(theta_deg), n2, sigma_ior=1.0)
        assert got == pytest.approx(slope, rel=0.03)


def _pooled(cases):
    """Share of the scored pixels whose normal and thickness errors lie within 2 σ, pooled."""
    from thinfilm.core.io import read_dataset
    from thinfilm.evaluation import geometry_error_maps

    within = np.zeros(2)
    total = 0
    for ds, est in cases:
        gt = read_dataset(ds, need=("ground_truth",), optional=()).ground_truth
        maps = geometry_error_maps(gt, est)
        sel = gt["mask"] & est.valid
        ne, te = maps["normal_error_deg"][sel], maps["thickness_error_nm"][sel]
        assert np.all(np.isfinite(est.normal_sigma_deg[sel])) and np.all(np.isfinite(est.thickness_sigma_nm[sel]))
        assert np.all(est.normal_sigma_deg[sel] > 0) and np.all(est.thickness_sigma_nm[sel] > 0)
        within += [np.sum(ne <= 2 * est.normal_sigma_deg[sel]), np.sum(te <= 2 * est.thickness_sigma_nm[sel])]
        total += int(sel.sum())
    return within / total


@pytest.fixture(scope="module")
def suite_datasets(tmp_path_factory):
    """Two scenes of the standard suite (hemisphere, cylinder) at 64 px, their own seeds."""
    from thinfilm.core.variants import use_variant
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec
    from thinfilm.scenes import preset_file

    use_variant()
    out = []
    for name in ("hemisphere_mgf2", "cylinder_sio2"):
        ds = tmp_path_factory.mktemp("cal") / name
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            generate_dataset(load_spec(preset_file(f"standard/{name}"), resolution=64), ds, progress=False)
        out.append(ds)
    return out


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["rgb", "spectral"])
def test_the_defaults_sigma_is_calibrated_on_rendered_scenes(suite_datasets, kind):
    """The true error lies within 2 σ for 88-99.5 % of the pixels (the band the standard suite
    holds, ``benchmarks/standard_suite.py``), normals and thickness, for each default."""
    from thinfilm.reconstruct import reconstruct

    cases = []
    for ds in suite_datasets:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            est, _ = reconstruct(kind, ds, None)
        cases.append((ds, est))
    normal, thickness = _pooled(cases)
    assert 0.88 <= normal <= 0.995, normal
    assert 0.88 <= thickness <= 0.995, thickness


@pytest.mark.slow
def test_the_s_only_path_reports_a_calibrated_sigma(suite_datasets, tmp_path):
    """The s spectra alone (no Stokes cube, as ``import spectral`` gives): the default runs
    ``eikonal-s``, and its σ covers its errors as the Stokes path's does."""
    from thinfilm.reconstruct import reconstruct

    cases = []
    for src in suite_datasets:
        ds = tmp_path / src.name
        shutil.copytree(src, ds)
        (ds / "stokes_spectral.exr").unlink()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            est, _ = reconstruct("spectral", ds, None)
        assert est.info["capture"] == "s"
        cases.append((ds, est))
    normal, thickness = _pooled(cases)
    assert 0.88 <= normal <= 0.995, normal
    assert 0.88 <= thickness <= 0.995, thickness
