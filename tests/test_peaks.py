"""Sub-band peak detection: positions against the interference condition (Eq. 28), values against
``tmm``'s bare-substrate reflectance (Eq. 21), and the no-peak / several-peak cases."""

import numpy as np
import pytest
import tmm

from thinfilm.bsdf.optics import reflectances
from thinfilm.reconstruction.peaks import PEAK_NONE, PEAK_OK, PEAK_SEVERAL, find_peaks

WL = np.arange(400.0, 721.0, 4.0)
N2, N3 = 1.37, 1.6


def _spectrum(theta_deg, d_nm):
    return reflectances(np.cos(np.radians(theta_deg)), WL, d_nm, N2, N3)[0]


def _constructive_wavelengths(theta_deg, d_nm):
    """m λ = 2 d sqrt(n2² - sin² θ) (paper Eq. 28), the orders inside the measured range."""
    path = 2 * d_nm * np.sqrt(N2**2 - np.sin(np.radians(theta_deg)) ** 2)
    lam = path / np.arange(1, 20)
    return np.sort(lam[(lam > WL[0]) & (lam < WL[-1])])[::-1]


def _substrate_rs(theta_deg):
    return tmm.coh_tmm("s", [1.0, N3], [np.inf, np.inf], np.radians(theta_deg), 550.0)["R"]


@pytest.mark.parametrize("theta_deg", [0.0, 10.0, 30.0, 50.0, 62.0])
def test_single_peak_position_and_value(theta_deg):
    p = find_peaks(_spectrum(theta_deg, 400.0)[None], WL)
    expected = _constructive_wavelengths(theta_deg, 400.0)
    assert expected.size == 1
    assert p.count[0] == 1 and p.status[0] == PEAK_OK
    # sub-band: 4 nm bands, position within 0.1 nm
    assert abs(p.wavelength_nm[0] - expected[0]) < 0.1
    # the peak reflectance is the bare substrate's (e^{iΔ} = 1), checked against tmm
    assert p.value[0] == pytest.approx(_substrate_rs(theta_deg), rel=1e-3)


def test_several_peaks_all_reported():
    p = find_peaks(_spectrum(30.0, 900.0)[None], WL)
    expected = _constructive_wavelengths(30.0, 900.0)
    assert expected.size == 2
    assert p.count[0] == 2 and p.status[0] == PEAK_SEVERAL
    np.testing.assert_allclose(p.all_wavelength_nm[0], expected, atol=0.2)
    assert p.mean_value[0] == pytest.approx(_substrate_rs(30.0), rel=2e-3)


def test_no_peak_in_range_is_reported_not_dropped():
    # at 75° the m = 2 peak of a 400 nm film lies below 400 nm and m = 1 above 720 nm
    assert _constructive_wavelengths(75.0, 400.0).size == 0
    S = np.stack([_spectrum(75.0, 400.0), _spectrum(30.0, 400.0)])
    p = find_peaks(S, WL)
    assert p.count.tolist() == [0, 1]
    assert p.status[0] == PEAK_NONE and np.isnan(p.wavelength_nm[0]) and np.isnan(p.value[0])


def test_maximum_on_the_first_band_is_not_a_peak():
    S = np.linspace(0.2, 0.1, WL.size)[None]  # decreasing: the maximum is outside the range
    assert find_peaks(S, WL).count[0] == 0


def test_noise_makes_no_spurious_peaks():
    rng = np.random.default_rng(3)
    clean = _spectrum(35.0, 400.0)
    S = clean[None] * (1.0 + 0.03 * rng.standard_normal((400, WL.size)))
    p = find_peaks(S, WL)
    assert np.mean(p.count == 1) >= 0.97
    ok = p.count == 1
    expected = _constructive_wavelengths(35.0, 400.0)[0]
    assert np.median(np.abs(p.wavelength_nm[ok] - expected)) < 3.0
    # the noise estimate sees the 3 % per band
    assert np.median(p.noise) == pytest.approx(0.03 * clean.mean(), rel=0.25)


def test_shapes_are_checked():
    with pytest.raises(ValueError, match=r"spectra must be \(N, 81\), got \(2, 5\)"):
        find_peaks(np.zeros((2, 5)), WL)
