"""The optics core against independent references: tmm, Mitsuba's Fresnel/Mueller code, published indices."""


import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import tmm  # noqa: E402

from thinfilm.bsdf import materials, optics  # noqa: E402

ANGLES = [0.0, 10.0, 30.0, 45.0, 56.0, 70.0, 85.0]
WAVELENGTHS = [400.0, 532.0, 633.0, 720.0]
THICKNESSES = [0.0, 1.0, 120.0, 400.0, 690.0, 1000.0]
# (film n2, film k2, substrate n3, substrate k3): dielectric, high-index film, metal substrates,
# an absorbing film.
STACKS = [
    (1.37, 0.0, 1.6, 0.0),
    (2.3, 0.0, 1.5, 0.0),
    (1.38, 0.0, 0.27, 3.4),   # MgF2-like on a silver-like conductor
    (1.45, 0.0, 1.2, 7.0),    # on an aluminium-like conductor
    (1.9, 0.05, 1.52, 0.0),   # weakly absorbing film
    (1.6, 0.0, 1.37, 0.0),    # film index above the substrate's
]


def _tmm(pol, theta_deg, lam, d, n2, k2, n3, k3):
    n_list = [1.0, complex(n2, k2), complex(n3, k3)]
    if d == 0:
        n_list, d_list = [1.0, complex(n3, k3)], [np.inf, np.inf]
    else:
        d_list = [np.inf, d, np.inf]
    return tmm.coh_tmm(pol, n_list, d_list, np.radians(theta_deg), lam)


@pytest.mark.parametrize("stack", STACKS)
def test_amplitudes_and_reflectances_match_tmm(stack):
    n2, k2, n3, k3 = stack
    th, lam, d = np.meshgrid(ANGLES, WAVELENGTHS, THICKNESSES, indexing="ij")
    r_s, r_p = optics.film_amplitudes(np.cos(np.radians(th)), lam, d, n2, n3, k3, film_k=k2)
    R_s, R_p = optics.reflectances(np.cos(np.radians(th)), lam, d, n2, n3, k3, film_k=k2)
    for idx in np.ndindex(th.shape):
        ref_s = _tmm("s", th[idx], lam[idx], d[idx], n2, k2, n3, k3)
        ref_p = _tmm("p", th[idx], lam[idx], d[idx], n2, k2, n3, k3)
        assert abs(R_s[idx] - ref_s["R"]) <= 1e-6
        assert abs(R_p[idx] - ref_p["R"]) <= 1e-6
        # Same sign convention as tmm: the complex amplitudes agree, not only |r|².
        assert abs(r_s[idx] - ref_s["r"]) <= 1e-9
        assert abs(r_p[idx] - ref_p["r"]) <= 1e-9
        # Phase difference δ = arg(r_s) − arg(r_p) in tmm's convention (Mitsuba's is its negative).
        if abs(ref_s["r"]) > 1e-6 and abs(ref_p["r"]) > 1e-6:
            delta_ref = np.angle(ref_s["r"] * np.conj(ref_p["r"]))
            delta = np.angle(r_s[idx] * np.conj(r_p[idx]))
            assert abs(np.angle(np.exp(1j * (delta - delta_ref)))) <= 1e-6


def test_broadcasting_over_leading_shapes():
    cos = np.cos(np.radians(np.linspace(0, 80, 5)))[:, None, None]
    lam = np.linspace(400, 700, 7)[None, :, None]
    d = np.linspace(0, 900, 3)[None, None, :]
    R_s, R_p = optics.reflectances(cos, lam, d, 1.37, 1.6)
    assert R_s.shape == R_p.shape == (5, 7, 3)
    M = optics.reflection_mueller(cos, lam, d, 1.37, 1.6)
    assert M.shape == (5, 7, 3, 4, 4)
    np.testing.assert_allclose(M[..., 0, 0], 0.5 * (R_s + R_p), rtol=0, atol=1e-15)


@pytest.mark.parametrize("eta", [1.6, 1.37, complex(0.27, 3.4), complex(1.2, 7.0), complex(2.5, 0.3)])
def test_bare_substrate_mueller_equals_mitsuba(variant_scalar_spectral_polarized, eta):
    """Thickness 0: our Mueller matrix equals Mitsuba's mueller.specular_reflection."""
    mi = variant_scalar_spectral_polarized
    import drjit as dr

    for theta in [0.0, 20.0, 45.0, 58.0, 75.0, 89.0]:
        c = float(np.cos(np.radians(theta)))
        ref = np.array(mi.mueller.specular_reflection(c, dr.scalar.Complex2f(eta.real, eta.imag)
                                                      if isinstance(eta, complex) else
                                                      dr.scalar.Complex2f(eta, 0.0)))
        ours = optics.reflection_mueller(c, 550.0, 0.0, 1.37, np.real(eta), np.imag(eta))
        np.testing.assert_allclose(ours, ref, atol=2e-6)


@settings(max_examples=300, deadline=None)
@given(
    theta=st.floats(0.0, 89.9),
    lam=st.floats(350.0, 1000.0),
    d=st.floats(0.0, 2000.0),
    n2=st.floats(1.0, 3.0),
    k2=st.floats(0.0, 0.5),
    n3=st.floats(0.05, 4.0),
    k3=st.floats(0.0, 10.0),
)
def test_energy_reflectances_within_unit_interval(theta, lam, d, n2, k2, n3, k3):
    R_s, R_p = optics.reflectances(np.cos(np.radians(theta)), lam, d, n2, n3, k3, film_k=k2)
    assert 0.0 <= R_s <= 1.0 + 1e-12
    assert 0.0 <= R_p <= 1.0 + 1e-12
    a, b, c, s = optics.mueller_entries(*optics.film_amplitudes(
        np.cos(np.radians(theta)), lam, d, n2, n3, k3, film_k=k2))
    # A physical (non-depolarizing) Mueller matrix: c² + s² = R_s R_p.
    assert abs(c * c + s * s - R_s * R_p) <= 1e-12


@settings(max_examples=300, deadline=None)
@given(theta=st.floats(0.0, 89.9), n=st.floats(1.01, 4.0), k=st.floats(0.0, 10.0))
def test_bare_interface_s_reflects_at_least_p(theta, n, k):
    """Single interfaces (dielectric or conductor): R_s >= R_p at every angle."""
    R_s, R_p = optics.reflectances(np.cos(np.radians(theta)), 550.0, 0.0, 1.5, n, k)
    assert R_s >= R_p - 1e-12


def test_brewster_angle_of_bare_dielectric():
    """R_p vanishes at Brewster's angle arctan(n) (analytic)."""
    n = 1.6
    _, R_p = optics.reflectances(np.cos(np.arctan(n)), 550.0, 0.0, 1.37, n)
    assert R_p < 1e-20


def test_quarter_wave_antireflection():
    """Analytic: a quarter-wave film with n2 = sqrt(n3) reflects nothing at normal incidence."""
    n3 = 1.9
    n2 = np.sqrt(n3)
    lam = 550.0
    R_s, R_p = optics.reflectances(1.0, lam, lam / (4 * n2), n2, n3)
    assert R_s < 1e-20 and R_p < 1e-20
    # Half-wave film: the bare-substrate value ((n3-1)/(n3+1))².
    R_s, _ = optics.reflectances(1.0, lam, lam / (2 * n2), n2, n3)
    assert abs(R_s - ((n3 - 1) / (n3 + 1)) ** 2) < 1e-12


def test_drjit_backend_matches_numpy(variant_llvm_ad_spectral):
    mi = variant_llvm_ad_spectral
    th = np.linspace(0, 85, 11)
    lam = np.linspace(400, 700, 11)
    d = np.linspace(0, 1000, 11)
    r_s, r_p = optics.film_amplitudes(mi.Float(np.cos(np.radians(th))), mi.Float(lam), mi.Float(d), 1.37, 0.27, 3.4)
    ref_s, ref_p = optics.film_amplitudes(np.cos(np.radians(th)), lam, d, 1.37, 0.27, 3.4)
    np.testing.assert_allclose(np.array(r_s.re) + 1j * np.array(r_s.im), ref_s, atol=2e-5)
    np.testing.assert_allclose(np.array(r_p.re) + 1j * np.array(r_p.im), ref_p, atol=2e-5)


@pytest.mark.parametrize(
    "name, wavelength, published",
    [
        ("BK7", 587.56, 1.5168),   # SCHOTT N-BK7 data sheet, n_d
        ("SiO2", 587.56, 1.4585),  # fused silica n_d (Malitson 1965)
        ("MgF2", 589.3, 1.3777),   # MgF2 ordinary n_D (Dodge 1984)
        ("PET", 550.0, 1.60),      # value the paper uses for its PET substrate
    ],
)
def test_named_materials_match_published_indices(name, wavelength, published):
    assert abs(float(materials.named_material(name)(wavelength)) - published) < 6e-4


def test_material_errors_are_clear():
    with pytest.raises(ValueError, match="unknown material 'unobtainium'"):
        materials.as_dispersion("unobtainium")
    with pytest.raises(ValueError, match="expected a number"):
        materials.as_dispersion([1, 2])
    assert materials.as_dispersion("1.5")(500.0) == 1.5
    cauchy = materials.as_dispersion({"cauchy": [1.5, 0.004]})
    assert abs(cauchy(400.0) - (1.5 + 0.004 / 0.16)) < 1e-12


@pytest.mark.parametrize("eta", [complex(1.6, 0.0), complex(0.27, 3.4), complex(2.5, 0.3)])
def test_phase_convention_relative_to_mitsuba(variant_scalar_spectral_polarized, eta):
    """Documented convention: our (tmm's) amplitudes are the complex conjugates of Mitsuba's."""
    mi = variant_scalar_spectral_polarized
    import drjit as dr

    for theta in [0.0, 30.0, 60.0, 80.0]:
        c = float(np.cos(np.radians(theta)))
        a_s, a_p, *_ = mi.fresnel_polarized(c, dr.scalar.Complex2f(eta.real, eta.imag))
        r_s, r_p = optics.interface_amplitudes(c, 1.0, eta.real, eta.imag)
        assert abs(np.conj(r_s) - complex(a_s[0], a_s[1])) < 2e-6
        assert abs(np.conj(r_p) - complex(a_p[0], a_p[1])) < 2e-6


@pytest.mark.parametrize("n1", [1.33, 1.5])
def test_exterior_medium_other_than_air_matches_tmm(n1):
    """A film seen from water or glass (n1 != 1), including total internal reflection."""
    for theta in [0.0, 20.0, 45.0, 70.0]:
        for d in [0.0, 350.0]:
            c = np.cos(np.radians(theta))
            r_s, r_p = optics.film_amplitudes(c, 520.0, d, 1.38, 1.6, ext_ior=n1)
            n_list = [n1, 1.38, 1.6] if d else [n1, 1.6]
            d_list = [np.inf, d, np.inf] if d else [np.inf, np.inf]
            ref_s = tmm.coh_tmm("s", n_list, d_list, np.radians(theta), 520.0)["r"]
            ref_p = tmm.coh_tmm("p", n_list, d_list, np.radians(theta), 520.0)["r"]
            assert abs(r_s - ref_s) < 1e-9 and abs(r_p - ref_p) < 1e-9


def test_weak_absorption_keeps_its_precision():
    """A nearly lossless film (k2 = 1e-9) near total internal reflection: the tiny absorption
    must survive the complex square root (found by the energy property test)."""
    args = ([1.0, complex(1.0, 1e-9), 0.5], [np.inf, 1.0, np.inf], np.radians(31.0), 350.0)
    R_s, R_p = optics.reflectances(np.cos(np.radians(31.0)), 350.0, 1.0, 1.0, 0.5, film_k=1e-9)
    assert abs(R_s - tmm.coh_tmm("s", *args)["R"]) < 1e-13
    assert abs(R_p - tmm.coh_tmm("p", *args)["R"]) < 1e-13
    assert R_s < 1.0 and R_p < 1.0
