"""Film stacks in the optics core against tmm, colour-science's multilayer_tmm, Mitsuba's
Fresnel/Mueller code and analytic properties (energy, reciprocity); the stack parser."""

import warnings

import numpy as np
import pytest
import tmm

from thinfilm.bsdf import materials, optics

LAM0 = 550.0
ANGLES = np.array([0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 85.0])
WAVELENGTHS = np.array([400.0, 450.0, 500.0, 550.0, 600.0, 650.0, 700.0])

# name: (exterior index, [(index, thickness_nm), ...] from the exterior down, substrate index)
STACKS = {
    # Quarter-wave MgF2 on glass, and the classic quarter-quarter MgF2 / ZrO2 two-layer coating.
    "ar_quarter_wave": (1.0, [(1.38, LAM0 / (4 * 1.38))], 1.52),
    "ar_two_layer": (1.0, [(1.38, LAM0 / (4 * 1.38)), (2.05, LAM0 / (4 * 2.05))], 1.52),
    # 10 pairs of quarter-wave TiO2-like / MgF2 layers on glass.
    "bragg_10": (1.0, [(2.35, LAM0 / (4 * 2.35)), (1.38, LAM0 / (4 * 1.38))] * 10, 1.52),
    # Absorbing layers (a dye-like film, a thin metal-like film), seen from water.
    "absorbing": (1.33, [(2.0 + 0.3j, 40.0), (1.46, 120.0), (1.7 + 0.05j, 80.0), (0.5 + 2.4j, 8.0)], 1.52),
    # A dielectric coating on a silver-like and on an aluminium-like metal.
    "metal_silver": (1.0, [(1.38, 100.0), (2.1, 60.0)], 0.27 + 3.4j),
    "metal_aluminium": (1.0, [(1.45, 180.0)], 1.2 + 7.0j),
}


def _tmm(pol, n1, layers, substrate, theta_deg, lam):
    n_list = [n1] + [complex(n) for n, _ in layers] + [complex(substrate)]
    d_list = [np.inf] + [d for _, d in layers] + [np.inf]
    return tmm.coh_tmm(pol, n_list, d_list, np.radians(theta_deg), lam)


def _ours(n1, layers, substrate, cos, lam):
    sub = complex(substrate)
    amps = optics.stack_amplitudes(cos, lam, layers, sub.real, sub.imag, n1, transmission=True)
    powers = optics.stack_powers(cos, lam, layers, sub.real, sub.imag, n1)
    return amps, powers


@pytest.mark.parametrize("name", sorted(STACKS))
def test_stack_amplitudes_and_powers_match_tmm(name):
    """r, t (complex, tmm's conventions), R and T on a wavelength × angle grid, |Δ| ≤ 1e-9."""
    n1, layers, substrate = STACKS[name]
    th, lam = np.meshgrid(ANGLES, WAVELENGTHS, indexing="ij")
    (r_s, r_p, t_s, t_p), (R_s, R_p, T_s, T_p) = _ours(n1, layers, substrate, np.cos(np.radians(th)), lam)
    worst = 0.0
    for idx in np.ndindex(th.shape):
        for pol, r, t, R, T in (("s", r_s, t_s, R_s, T_s), ("p", r_p, t_p, R_p, T_p)):
            ref = _tmm(pol, n1, layers, substrate, th[idx], lam[idx])
            worst = max(worst, abs(r[idx] - ref["r"]), abs(R[idx] - ref["R"]))
            if np.imag(substrate) == 0:  # no transmitted wave into a metal
                worst = max(worst, abs(t[idx] - ref["t"]), abs(T[idx] - ref["T"]))
    assert worst <= 1e-9


def test_bragg_mirror_reflects_inside_its_stop_band():
    """The quarter-wave mirror at normal incidence: the analytic ``((Y - 1) / (Y + 1))²`` with the
    admittance ``Y = (nH/nL)^2N n_sub`` at its design wavelength (R > 0.999), and a stop band whose
    half width in wavenumber is ``(2/π) arcsin((nH - nL)/(nH + nL)) / λ0``."""
    n1, layers, substrate = STACKS["bragg_10"]
    nH, nL, N = 2.35, 1.38, 10
    R_s = optics.stack_powers(1.0, LAM0, layers, substrate)[0]
    # From the exterior the stack reads H L H L ... H L | substrate; a quarter-wave layer of index n
    # turns the admittance Y below it into n²/Y.
    Y = (nH / nL) ** (2 * N) * substrate
    assert abs(R_s - ((Y - 1) / (Y + 1)) ** 2) <= 1e-12 and R_s > 0.999
    half_width = LAM0 * (2 / np.pi) * np.arcsin((nH - nL) / (nH + nL))  # in frequency: Δg
    inside = 1 / (1 / LAM0 + 0.8 * half_width / LAM0**2)
    outside = 1 / (1 / LAM0 + 1.6 * half_width / LAM0**2)
    assert optics.stack_powers(1.0, inside, layers, substrate)[0] > 0.99
    assert optics.stack_powers(1.0, outside, layers, substrate)[0] < 0.5


def _colour_multilayer(n1, layers, substrate, theta_deg, wavelengths):
    from colour.phenomena import multilayer_tmm

    n = [n1] + [complex(v) for v, _ in layers] + [complex(substrate)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        R, T = multilayer_tmm(n, [d for _, d in layers], wavelengths, theta_deg)
    return R[:, :, 0, :], T[:, :, 0, :]  # (W, A, [s, p])


@pytest.mark.parametrize("name", ["ar_quarter_wave", "ar_two_layer", "bragg_10"])
def test_lossless_stacks_match_colour_multilayer_tmm(name):
    """colour-science's transfer matrices (R and T of s and p; colour's r_p has the opposite sign
    to tmm's, which R does not see), every angle up to 85°."""
    n1, layers, substrate = STACKS[name]
    R_ref, T_ref = _colour_multilayer(n1, layers, substrate, ANGLES, WAVELENGTHS)
    cos = np.cos(np.radians(ANGLES))[None, :]
    R_s, R_p, T_s, T_p = optics.stack_powers(cos, WAVELENGTHS[:, None], layers, substrate, 0.0, n1)
    assert np.abs(np.stack([R_s, R_p], -1) - R_ref).max() <= 1e-9
    assert np.abs(np.stack([T_s, T_p], -1) - T_ref).max() <= 1e-9


@pytest.mark.parametrize("name", ["absorbing", "metal_silver", "metal_aluminium"])
def test_absorbing_stacks_match_colour_multilayer_tmm_at_normal_incidence(name):
    """colour-science uses n + ik with k ≥ 0 absorbing, as we do, but computes the refraction angles
    from the real parts of the indices (Snell's law on Re n), which is exact only at normal incidence
    once a medium absorbs (at 30° it is off by up to 0.05 in R for the absorbing stack, NaN for the
    metals): compare at normal incidence, R (and T for the dielectric substrate)."""
    n1, layers, substrate = STACKS[name]
    R_ref, T_ref = _colour_multilayer(n1, layers, substrate, 0.0, WAVELENGTHS)
    sub = complex(substrate)
    R_s, R_p, T_s, T_p = optics.stack_powers(1.0, WAVELENGTHS, layers, sub.real, sub.imag, n1)
    assert np.abs(np.stack([R_s, R_p], -1) - R_ref[:, 0]).max() <= 1e-9
    if sub.imag == 0:
        assert np.abs(np.stack([T_s, T_p], -1) - T_ref[:, 0]).max() <= 1e-9


@pytest.mark.parametrize("name", ["ar_two_layer", "bragg_10"])
def test_lossless_stacks_conserve_energy(name):
    n1, layers, substrate = STACKS[name]
    cos = np.cos(np.radians(np.linspace(0.0, 89.0, 40)))[:, None]
    lam = np.linspace(380.0, 780.0, 81)[None, :]
    R_s, R_p, T_s, T_p = optics.stack_powers(cos, lam, layers, substrate, 0.0, n1)
    assert np.abs(R_s + T_s - 1).max() <= 1e-12 and np.abs(R_p + T_p - 1).max() <= 1e-12
    # Free-standing (the exterior medium on both sides): |r|² + |t|² = 1.
    r_s, r_p, t_s, t_p = optics.sheet_amplitudes(cos, lam, layers, 1.0)
    assert np.abs(abs(r_s) ** 2 + abs(t_s) ** 2 - 1).max() <= 1e-12
    assert np.abs(abs(r_p) ** 2 + abs(t_p) ** 2 - 1).max() <= 1e-12


def test_absorbing_stack_loses_energy_and_stays_physical():
    n1, layers, substrate = STACKS["absorbing"]
    cos = np.cos(np.radians(ANGLES))[:, None]
    R_s, R_p, T_s, T_p = optics.stack_powers(cos, WAVELENGTHS[None, :], layers, substrate, 0.0, n1)
    for R, T in ((R_s, T_s), (R_p, T_p)):
        assert np.all(R >= 0) and np.all(T >= 0) and np.all(R + T < 1 - 1e-3)


def test_transmission_is_reciprocal():
    """Lorentz reciprocity: the same transmittance from both sides, absorbing layers included,
    while an asymmetric absorbing stack reflects differently from its two sides."""
    _, layers, _ = STACKS["absorbing"]
    cos = np.cos(np.radians(ANGLES))[:, None]
    lam = WAVELENGTHS[None, :]
    front = optics.sheet_amplitudes(cos, lam, layers, 1.0)
    back = optics.sheet_amplitudes(cos, lam, layers[::-1], 1.0)
    np.testing.assert_allclose(front[2], back[2], rtol=0, atol=1e-13)
    np.testing.assert_allclose(front[3], back[3], rtol=0, atol=1e-13)
    assert np.abs(abs(front[0]) - abs(back[0])).max() > 0.05
    # On a substrate: from air at θ, and from the glass at the refracted angle (layers reversed).
    n_sub = 1.52
    sin1 = np.sin(np.radians(ANGLES))[:, None]
    cos_sub = np.sqrt(1 - (sin1 / n_sub) ** 2)
    T_in = optics.stack_powers(cos, lam, layers, n_sub, 0.0, 1.0)
    T_out = optics.stack_powers(cos_sub, lam, layers[::-1], 1.0, 0.0, n_sub)
    np.testing.assert_allclose(T_in[2], T_out[2], rtol=0, atol=1e-12)
    np.testing.assert_allclose(T_in[3], T_out[3], rtol=0, atol=1e-12)


FILMS = [  # (film n, film k, substrate n, substrate k, exterior n), as in test_optics.py
    (1.37, 0.0, 1.6, 0.0, 1.0),
    (2.3, 0.0, 1.5, 0.0, 1.0),
    (1.38, 0.0, 0.27, 3.4, 1.0),
    (1.45, 0.0, 1.2, 7.0, 1.0),
    (1.9, 0.05, 1.52, 0.0, 1.0),
    (1.6, 0.0, 1.37, 0.0, 1.0),
    (1.38, 0.0, 1.6, 0.0, 1.33),
    (1.0, 1e-9, 0.5, 0.0, 1.0),
]


@pytest.mark.parametrize("film", FILMS)
def test_reflection_does_not_depend_on_computing_transmission(film):
    """The recursion with and without its transmission terms gives the same reflection
    amplitudes, bit for bit (the single film, ``film_amplitudes``, is its one-layer case)."""
    n2, k2, n3, k3, n1 = film
    cos = np.cos(np.radians(np.linspace(0.0, 89.9, 31)))[:, None, None]
    lam = np.linspace(350.0, 1000.0, 17)[None, :, None]
    d = np.linspace(0.0, 2000.0, 23)[None, None, :]
    ref = optics.stack_amplitudes(cos, lam, [(n2, k2, d)], n3, k3, n1)
    ours = optics.stack_amplitudes(cos, lam, [(n2, k2, d)], n3, k3, n1, transmission=True)
    assert np.array_equal(ours[0], ref[0]) and np.array_equal(ours[1], ref[1])


def test_drjit_backend_matches_numpy_for_stacks(variant_llvm_ad_spectral):
    """Float32 lanes (llvm_ad_spectral) and double precision (drjit.llvm.Float64)."""
    import drjit as dr

    mi = variant_llvm_ad_spectral
    n1, layers, substrate = STACKS["absorbing"]
    rng = np.random.default_rng(5)
    cos, lam, scale = rng.uniform(0, 1, 101), rng.uniform(380, 780, 101), rng.uniform(0.5, 1.5, 101)
    sub = complex(substrate)
    ref = optics.stack_amplitudes(cos, lam, [(n, d * scale) for n, d in layers], sub.real, sub.imag,
                                  n1, transmission=True)
    for Float, atol in ((mi.Float, 2e-5), (dr.llvm.Float64, 1e-12)):
        dl = [(complex(n).real, complex(n).imag, Float(d * scale)) for n, d in layers]
        ours = optics.stack_amplitudes(Float(cos), Float(lam), dl, sub.real, sub.imag, n1,
                                       transmission=True)
        for a, b in zip(ours, ref):
            np.testing.assert_allclose(np.array(a.re) + 1j * np.array(a.im), b, rtol=0, atol=atol)


@pytest.mark.parametrize("eta", [1.5, 1.33, 2.4])
def test_bare_interface_transmission_mueller_equals_mitsuba(variant_scalar_spectral_polarized, eta):
    """No layer: our transmission Mueller entries (tmm's t with the intensity factor) equal Mitsuba's
    mueller.specular_transmission, and the reflection entries its specular_reflection."""
    mi = variant_scalar_spectral_polarized
    for theta in [0.0, 20.0, 45.0, 60.0, 80.0]:
        c = float(np.cos(np.radians(theta)))
        r_s, r_p, t_s, t_p = optics.stack_amplitudes(c, 550.0, [], eta, transmission=True)
        f_s, f_p = optics.transmission_factors(c, eta)
        assert abs(f_s - f_p) <= 1e-14 * f_s
        ours_t = optics.mueller_matrix(*optics.transmission_mueller_entries(t_s, t_p, f_s))
        ours_r = optics.mueller_matrix(*optics.mueller_entries(r_s, r_p))
        np.testing.assert_allclose(ours_t, np.array(mi.mueller.specular_transmission(c, eta)), atol=2e-6)
        np.testing.assert_allclose(ours_r, np.array(mi.mueller.specular_reflection(c, eta)), atol=2e-6)


@pytest.mark.parametrize("name", ["ar_two_layer", "absorbing"])
def test_sheet_mueller_against_tmm(name):
    """Free-standing stack: M_r and M_t from tmm's amplitudes (c + i s = conj(x_s) x_p), M_t[0,0]
    and M_r[0,0] are tmm's mean T and R; thickness 0 transmits as the identity."""
    _, layers, _ = STACKS[name]
    for theta in (0.0, 35.0, 70.0):
        for lam in (430.0, 560.0, 690.0):
            M_r, M_t = optics.sheet_mueller(np.cos(np.radians(theta)), lam, layers, 1.0)
            ref = {pol: _tmm(pol, 1.0, layers, 1.0, theta, lam) for pol in "sp"}
            for M, key, power in ((M_r, "r", "R"), (M_t, "t", "T")):
                x = np.conj(ref["s"][key]) * ref["p"][key]
                assert abs(M[0, 0] - 0.5 * (ref["s"][power] + ref["p"][power])) <= 1e-12
                assert abs(M[0, 1] - 0.5 * (ref["s"][power] - ref["p"][power])) <= 1e-12
                assert abs(M[2, 2] - x.real) <= 1e-12 and abs(M[2, 3] - x.imag) <= 1e-12
                assert abs(M[3, 2] + x.imag) <= 1e-12 and abs(M[3, 3] - x.real) <= 1e-12
    zero = [(n, 0.0) for n, _ in layers]
    M_r, M_t = optics.sheet_mueller(np.cos(np.radians([0.0, 40.0, 80.0])), 550.0, zero, 1.0)
    np.testing.assert_allclose(M_t, np.broadcast_to(np.eye(4), M_t.shape), atol=1e-12)
    np.testing.assert_allclose(M_r, 0.0, atol=1e-12)


def test_stack_layers_accept_parsed_materials_and_broadcast():
    """Layers from parse_stack (a dispersive, a complex and a plain index) over a 3-D grid."""
    stack = materials.parse_stack("MgF2:95, 2.1:62, 1.65+0.01i:80")
    cos = np.cos(np.radians(np.linspace(0, 80, 5)))[:, None, None]
    lam = np.linspace(400, 700, 7)[None, :, None]
    scale = np.linspace(0.5, 1.5, 3)[None, None, :]
    layers = [(n, k, d * scale) for n, k, d in (layer.at(lam) for layer in stack)]
    R_s, R_p, T_s, T_p = optics.stack_powers(cos, lam, layers, 1.52)
    assert R_s.shape == (5, 7, 3)
    mgf2 = materials.named_material("MgF2")
    for i, j, k in [(0, 0, 0), (3, 5, 2), (4, 6, 1)]:
        th = np.degrees(np.arccos(cos[i, 0, 0]))
        n_list = [1.0, float(mgf2(lam[0, j, 0])), 2.1, 1.65 + 0.01j, 1.52]
        d_list = [np.inf] + [d * scale[0, 0, k] for d in (95.0, 62.0, 80.0)] + [np.inf]
        ref = tmm.coh_tmm("p", n_list, d_list, np.radians(th), lam[0, j, 0])
        assert abs(R_p[i, j, k] - ref["R"]) <= 1e-9 and abs(T_p[i, j, k] - ref["T"]) <= 1e-9


def test_named_absorbing_material_matches_its_model():
    """The Au table: Rakić et al.'s Lorentz-Drude model, sampled at its own grid points, and its
    extinction reaches the optics (a 20 nm gold film on glass against tmm)."""
    au = materials.named_material("Au")
    hc = 1239.84198
    w = hc / 550.0
    eps = 1 - 0.760 * 9.03**2 / (w * (w + 0.053j))
    for f, g, wj in [(0.024, 0.241, 0.415), (0.010, 0.345, 0.830), (0.071, 0.870, 2.969),
                     (0.601, 2.494, 4.304), (4.384, 2.214, 13.32)]:
        eps += f * 9.03**2 / (wj**2 - w**2 - 1j * w * g)
    assert abs(au(550.0) + 1j * au.extinction(550.0) - np.sqrt(eps)) < 1e-6
    layer = materials.parse_stack("Au:20")[0]
    R_s, R_p, T_s, T_p = optics.stack_powers(np.cos(np.radians(40.0)), 600.0, [layer.at(600.0)], 1.52)
    n_au = complex(float(au(600.0)), float(au.extinction(600.0)))
    for pol, R, T in (("s", R_s, T_s), ("p", R_p, T_p)):
        ref = tmm.coh_tmm(pol, [1.0, n_au, 1.52], [np.inf, 20.0, np.inf], np.radians(40.0), 600.0)
        assert abs(R - ref["R"]) <= 1e-9 and abs(T - ref["T"]) <= 1e-9
    assert R_s + T_s < 0.9  # the film absorbs


def test_water_table_is_schiebener():
    """H2O: n_D of water at 20 °C is 1.33299 relative to air (CRC handbook), i.e. 1.33336 relative to
    vacuum (n_air = 1.000277), the index the optics use."""
    assert abs(float(materials.named_material("H2O")(589.3)) - 1.33299 * 1.000277) < 5e-5


# --- the stack parser -----------------------------------------------------------------------------


def test_parse_stack_reads_numbers_complex_indices_and_materials():
    stack = materials.parse_stack(" MgF2 : 95 ,2.1:62, 1.65+0.01i:80, 1.5 + 0.2j:0, h2o:1e3")
    assert [layer.thickness_nm for layer in stack] == [95.0, 62.0, 80.0, 0.0, 1000.0]
    assert stack[0].material.name == "MgF2" and stack[4].material.name == "H2O"
    assert stack[1].material == materials.Constant(2.1, 0.0)
    assert stack[2].material == materials.Constant(1.65, 0.01)
    assert stack[3].material == materials.Constant(1.5, 0.2)
    pairs = materials.parse_stack([(1.5, 10), (1.6 + 0.1j, 20.0), ("Au", 5)])
    assert pairs[1].material == materials.Constant(1.6, 0.1) and pairs[2].material.name == "Au"


@pytest.mark.parametrize("text, message", [
    ("", "stack is empty"),
    ("MgF2 95", "stack item 'MgF2 95': expected INDEX:THICKNESS_NM"),
    ("1.5:10,", "stack '1.5:10,': item 2 is empty"),
    ("Unobtainium:95", "stack item 'Unobtainium:95': unknown material 'Unobtainium'"),
    ("1.5:-3", "stack item '1.5:-3': the thickness must be finite and >= 0 nm"),
    ("1.5:ten", "stack item '1.5:ten': the thickness 'ten' must be a number of nm"),
    ("1.5-0.1i:10", "stack item '1.5-0.1i:10': refractive index '1.5-0.1i': the extinction k must"),
    ("0:10", "stack item '0:10': refractive index '0': the real part must be a finite number > 0"),
    ("1.5:1:2", "stack item '1.5:1:2': expected INDEX:THICKNESS_NM"),
])
def test_parse_stack_errors_name_the_item(text, message):
    with pytest.raises(ValueError, match="^" + message.replace("(", r"\(").replace("+", r"\+")) as e:
        materials.parse_stack(text)
    assert "\n" not in str(e.value)


def test_stack_layer_errors_are_clear():
    with pytest.raises(ValueError, match=r"stack layer 1: expected \(n, k, thickness_nm\)"):
        optics.stack_amplitudes(1.0, 550.0, [(1.5, 0.0, 10.0), (1.5,)], 1.6)
