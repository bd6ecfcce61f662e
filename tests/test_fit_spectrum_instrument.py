"""The instrument in ``fit_spectra``: line width, thickness spread, runner-up, honest sigma.

Synthetic readings come from an independent simple implementation, not the project's model:
the analytic Airy reflectance of a free-standing non-absorbing film, averaged over a Gaussian
thickness spread by a dense explicit sum, convolved with a Gaussian line by ``np.convolve`` on
a fine grid and sampled at the measured wavelengths, times a smooth response, plus a
background and noise.
"""

import json

import numpy as np
import pytest

from thinfilm.cli import main
from thinfilm.reconstruction.spectrum_fit import FilmModel, fit_spectra

LAM = np.linspace(450.0, 800.0, 500)
N_FILM = 1.33


def airy(lam, d, n=N_FILM):
    """Normal-incidence reflectance of a film of index n in air (Airy formula)."""
    r = (1.0 - n) / (1.0 + n)
    F = 4.0 * r * r / (1.0 - r * r) ** 2
    s = np.sin(2.0 * np.pi * n * d / lam) ** 2
    return F * s / (1.0 + F * s)


def reading(lam, d, spread, fwhm, h=0.02):
    """R seen through a thickness spread (standard deviation) and a Gaussian line (FWHM), each
    pixel integrating over its width (the sample spacing of the uniform ``lam``).

    On a fine grid through the samples (``m`` steps a pixel): a dense sum over the spread, a
    discrete convolution with the line, then each pixel's mean (trapezoid) read off the grid."""
    step = lam[1] - lam[0]
    m = int(np.ceil(step / h))
    h = step / m
    pad = int(np.ceil(60.0 / h))
    fine = lam[0] + h * np.arange(-pad, (lam.size - 1) * m + pad + 1)
    if spread > 0:
        x = np.linspace(-4.5, 4.5, 91)
        w = np.exp(-0.5 * x * x)
        w /= w.sum()
        R = sum(wi * airy(fine, max(d + spread * xi, 0.0)) for xi, wi in zip(x, w))
    else:
        R = airy(fine, d)
    if fwhm > 0:
        sig = fwhm / (2.0 * np.sqrt(2.0 * np.log(2.0)))
        half = int(np.ceil(6.0 * sig / h))
        k = np.exp(-0.5 * (h * np.arange(-half, half + 1) / sig) ** 2)
        R = np.convolve(R, k / k.sum(), mode="same")
    box = np.ones(m + 1)
    box[[0, -1]] = 0.5
    R = np.convolve(R, box / m, mode="same")
    return R[pad + m * np.arange(lam.size)]


def raw(lam, R, rng, noise=0.005):
    t = (lam - lam.mean()) / (0.5 * np.ptp(lam))
    response = 1000.0 * np.exp(rng.uniform(-0.4, 0.4) * t + rng.uniform(-0.3, 0.3) * t * t)
    background = 20.0 + rng.uniform(-5.0, 5.0) * t
    return background + response * R + rng.normal(0.0, noise * np.mean(response * R), lam.size)


MODEL = FilmModel(N_FILM, 1.0)


def test_a_given_resolution_recovers_thick_washed_out_films():
    """A 6 nm line washes out most of a 4 µm film's fringes at the blue end; given the width,
    the fit is within 0.5 % and its sigma covers the error."""
    rng = np.random.default_rng(3)
    truth = [3000.0, 4000.0]
    Y = np.stack([raw(LAM, reading(LAM, d, 0.0, 6.0), rng) for d in truth])
    for f, d in zip(fit_spectra(LAM, Y, MODEL, resolution_nm=6.0, thickness_spread_nm=0.0), truth):
        assert abs(f.thickness_nm - d) <= 0.005 * d, (d, f.thickness_nm)
        assert abs(f.thickness_nm - d) <= 3.0 * f.thickness_sigma_nm, (d, f.thickness_nm, f.thickness_sigma_nm)
        assert f.resolution_nm == 6.0 and f.thickness_spread_nm == 0.0


def test_the_line_width_and_spread_are_fitted_when_not_given():
    """Neither given: the fit picks an instrument setting that washes the fringes out as the
    data do, and the thickness is right."""
    rng = np.random.default_rng(5)
    cases = [(2500.0, 25.0, 0.0), (3500.0, 0.0, 10.0), (1500.0, 40.0, 5.0)]
    Y = np.stack([raw(LAM, reading(LAM, d, s, w), rng) for d, s, w in cases])
    for f, (d, s, w) in zip(fit_spectra(LAM, Y, MODEL), cases):
        assert abs(f.thickness_nm - d) <= 0.01 * d, (d, f.thickness_nm, f.thickness_sigma_nm)
        assert abs(f.thickness_nm - d) <= 3.0 * f.thickness_sigma_nm
        assert f.thickness_spread_nm == pytest.approx(s, abs=15.0)
        assert f.chi2 < 3.0, f.chi2


def test_the_spread_lowers_the_model_contrast():
    """The model with a spread has fringes of lower contrast than without (the reading of the
    same film), while keeping their positions."""
    from thinfilm.reconstruction.spectrum_fit import instrument_reflectance

    d = 2000.0
    R0 = instrument_reflectance(LAM, MODEL, [d])[0]
    R1 = instrument_reflectance(LAM, MODEL, [d], thickness_spread_nm=30.0)[0]
    R2 = instrument_reflectance(LAM, MODEL, [d], resolution_nm=6.0)[0]
    assert np.ptp(R1) < 0.8 * np.ptp(R0)
    np.testing.assert_allclose(R0, reading(LAM, d, 0.0, 0.0), atol=5e-4 * R0.max())
    np.testing.assert_allclose(R1, reading(LAM, d, 30.0, 0.0), atol=5e-4 * R0.max())
    np.testing.assert_allclose(R2, reading(LAM, d, 0.0, 6.0), atol=5e-4 * R0.max())


def test_the_runner_up_is_another_reading_and_sigma_covers_the_ambiguity(tmp_path, capsys):
    """A thin film without background or reference can be read as another thickness; the
    runner-up is reported (another order, its chi-square, how much worse) and the sigma covers
    the error of the winner."""
    rng = np.random.default_rng(11)
    d = 250.0
    y = raw(LAM, reading(LAM, d, 0.0, 0.0), rng)
    f = fit_spectra(LAM, y, MODEL)[0]
    assert np.isfinite(f.runner_up_thickness_nm) and np.isfinite(f.runner_up_chi2)
    assert f.runner_up_delta_bic >= 0.0
    assert abs(f.runner_up_thickness_nm - f.thickness_nm) >= 0.25 * LAM[0] / (2.0 * N_FILM)
    assert abs(f.thickness_nm - d) <= 3.0 * f.thickness_sigma_nm, (f.thickness_nm, f.thickness_sigma_nm)
    path = tmp_path / "thin.csv"
    np.savetxt(path, np.column_stack([LAM, y]), delimiter=",")
    assert main(["fit-spectrum", str(path), "--film-ior", "1.33", "--substrate-ior", "1", "--json"]) == 0
    row = json.loads(capsys.readouterr().out)
    for key in ("runner_up_thickness_nm", "runner_up_chi2", "runner_up_delta_bic", "thickness_spread_nm",
                "resolution_nm"):
        assert key in row


@pytest.mark.parametrize("option", ["--resolution", "--thickness-spread"])
def test_a_bad_width_is_one_line_exit_2(tmp_path, capsys, option):
    path = tmp_path / "s.csv"
    np.savetxt(path, np.column_stack([LAM, 1.0 + airy(LAM, 1000.0)]), delimiter=",")
    code = main(["fit-spectrum", str(path), "--film-ior", "1.33", "--substrate-ior", "1", option, "-2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and option in err[0]


SIGMA_SEEDS = (101, 202)


def test_sigma_is_honest_with_a_random_spread_and_resolution():
    """Films of 500-4000 nm, a random thickness spread (0-50 nm) and line width (0-10 nm)
    unknown to the fit, 50 spectra for each of two seeds: the truth lies within 2 sigma for
    90-98 % of the fits."""
    z = []
    for seed in SIGMA_SEEDS:
        rng = np.random.default_rng(seed)
        count = 50
        d = np.exp(rng.uniform(np.log(500.0), np.log(4000.0), count))
        s = rng.uniform(0.0, 50.0, count)
        w = rng.uniform(0.0, 10.0, count)
        Y = np.stack([raw(LAM, reading(LAM, *v), rng) for v in zip(d, s, w)])
        fits = fit_spectra(LAM, Y, MODEL)
        z += [abs(f.thickness_nm - t) / f.thickness_sigma_nm for f, t in zip(fits, d)]
    inside = np.mean(np.asarray(z) <= 2.0)
    assert 0.90 <= inside <= 0.98, (inside, np.sort(z)[-8:])
