"""The ``thinfilm`` BSDF in Mitsuba's RGB variants.

References: the film's reflectance spectrum from colour-science's transfer-matrix code
(``colour.phenomena.thin_film_tmm``) converted to linear sRGB by colour-science
(``colour.msds_to_XYZ`` under D65, ``colour.XYZ_to_RGB``); Mitsuba's own spectral
rendering of the same scene (``llvm_ad_spectral``) converted to sRGB by Mitsuba's film;
Mitsuba's ``conductor`` in RGB.
"""

import numpy as np
import pytest
from conftest import variant

RGB_VARIANTS = ["scalar_rgb", "llvm_ad_rgb"]


def _lab(rgb):
    """CIE L*a*b* (D65 white) of linear sRGB values (..., 3)."""
    import colour

    xyz = colour.RGB_to_XYZ(np.asarray(rgb, dtype=np.float64), colour.RGB_COLOURSPACES["sRGB"],
                            apply_cctf_decoding=False)
    white = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    return colour.XYZ_to_Lab(xyz, white)


def _delta_e(rgb_a, rgb_b):
    import colour

    return colour.delta_E(_lab(rgb_a), _lab(rgb_b), method="CIE 1976")


def _srgb_under_d65(lam, R):
    """Linear sRGB of reflectance spectra ``R`` (wavelengths first) under D65, by colour-science.

    A perfect reflector gives (1, 1, 1). Returns shape ``R.shape[1:] + (3,)``.
    """
    import colour

    shape = R.shape[1:]
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(colour.SpectralShape(360, 830, 1))  # CIE's ends at 780
    msds = colour.MultiSpectralDistributions(R.reshape(len(lam), -1), lam)
    xyz = colour.msds_to_XYZ(msds, cmfs, d65, method="Integration", shape=colour.SpectralShape(360, 830, 1)) / 100.0
    rgb = colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_encoding=False)
    return rgb.reshape(*shape, 3)


def _colour_science_rgb(theta_deg, thickness_nm, film_ior, substrate_ior):
    """Linear sRGB under D65 of one film's unpolarized reflectance (colour's ``thin_film_tmm``).

    Returns an array (len(theta_deg), len(thickness_nm), 3).
    """
    from colour.phenomena import thin_film_tmm

    lam = np.arange(360.0, 831.0, 1.0)
    R, _ = thin_film_tmm([1.0, film_ior, substrate_ior], np.asarray(thickness_nm, dtype=np.float64), lam,
                         np.asarray(theta_deg, dtype=np.float64))
    return _srgb_under_d65(lam, R.mean(axis=-1))  # unpolarized: (R_s + R_p) / 2, (W, A, T)


def _interactions(mi, theta_deg):
    """Surface interactions lit/viewed at zenith angles ``theta_deg`` (one lane each)."""
    import drjit as dr

    t = np.radians(np.asarray(theta_deg, dtype=np.float64))
    si = dr.zeros(mi.SurfaceInteraction3f, len(t))
    si.wi = mi.Vector3f(mi.Float(np.sin(t)), mi.Float(0.0 * t), mi.Float(np.cos(t)))
    si.n = mi.Normal3f(0, 0, 1)
    si.sh_frame = mi.Frame3f(si.n)
    return si


def _sample_values(mi, bsdf, theta_deg):
    """The BSDF's sample() weight (RGB) for each incident angle, shape (len(theta_deg), 3)."""
    if mi.variant().startswith("scalar"):
        out = []
        for theta in theta_deg:
            t = np.radians(theta)
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(np.sin(t), 0.0, np.cos(t))
            si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
            _, value = bsdf.sample(mi.BSDFContext(), si, 0.5, mi.Point2f(0.5, 0.5))
            out.append([value[0], value[1], value[2]])
        return np.array(out, dtype=np.float64)
    si = _interactions(mi, theta_deg)
    _, value = bsdf.sample(mi.BSDFContext(), si, mi.Float(0.5), mi.Point2f(0.5, 0.5))
    return np.array(value, dtype=np.float64).reshape(3, -1).T


# --- loading and rendering -----------------------------------------------------------


@pytest.mark.parametrize("mitsuba_variant", RGB_VARIANTS, indirect=True)
def test_loads_and_renders_in_rgb_variants(mitsuba_variant):
    mi = mitsuba_variant
    bsdf = mi.load_dict({"type": "thinfilm", "thickness": 380.0, "film_ior": "MgF2", "substrate_ior": 1.6})
    value = _sample_values(mi, bsdf, [0.0, 45.0, 80.0])
    assert np.all(np.isfinite(value)) and np.all(value > 0) and np.all(value < 1)
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 3},
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 8, "height": 8},
                   "sampler": {"type": "independent", "sample_count": 2}},
        "emitter": {"type": "constant"},
        "sphere": {"type": "sphere", "bsdf": {"type": "thinfilm"}},
    })
    img = np.array(mi.render(scene), dtype=np.float64)
    assert img.shape == (8, 8, 3) and np.all(np.isfinite(img))
    assert img[3:5, 3:5].mean() > 0.01  # the sphere reflects the sky


@pytest.mark.parametrize("mitsuba_variant", RGB_VARIANTS, indirect=True)
def test_cornell_box_with_thin_film_sphere(mitsuba_variant):
    """Mitsuba's own Cornell box, with a thin-film sphere, loads and renders."""
    mi = mitsuba_variant
    variant = mi.variant()
    scene = mi.cornell_box()
    scene["sensor"]["film"]["width"] = scene["sensor"]["film"]["height"] = 8 if variant.startswith("scalar") else 16
    scene["sensor"]["sampler"]["sample_count"] = 2 if variant.startswith("scalar") else 4
    scene["film-sphere"] = {"type": "sphere", "radius": 0.3,
                            "to_world": mi.ScalarTransform4f().translate([-0.3, -0.4, 0.3]),
                            "bsdf": {"type": "thinfilm", "thickness": 450.0, "substrate_ior": 1.5}}
    img = np.array(mi.render(mi.load_dict(scene)), dtype=np.float64)
    assert np.all(np.isfinite(img)) and img.mean() > 0.01


# --- colour accuracy ----------------------------------------------------------------


THETAS = [0.0, 15.0, 30.0, 45.0, 60.0, 70.0, 80.0, 87.0]
THICKNESSES = [0.0, 120.0, 250.0, 400.0, 550.0, 700.0, 900.0]


@pytest.mark.parametrize("film_ior, substrate_ior", [(1.37, 1.6), (1.33, 1.0), (2.0, 1.5)])
def test_bsdf_colour_matches_colour_science(variant_llvm_ad_rgb, film_ior, substrate_ior):
    """Per-direction RGB values against colour-science's integral of the tmm spectrum (ΔE*ab).

    colour-science tabulates the CMFs and D65 at 1 nm (Mitsuba at 5 nm) and derives its own
    sRGB matrix, so this bounds table and quadrature differences together.
    """
    mi = variant_llvm_ad_rgb
    bsdf = mi.load_dict({"type": "thinfilm", "film_ior": film_ior, "substrate_ior": substrate_ior})
    params = mi.traverse(bsdf)
    ours = []
    for d in THICKNESSES:
        params["thickness"] = d
        params.update()
        ours.append(_sample_values(mi, bsdf, THETAS))
    ours = np.stack(ours, axis=1)  # (angles, thicknesses, 3)
    ref = _colour_science_rgb(THETAS, THICKNESSES, film_ior, substrate_ior)
    dE = _delta_e(ours, ref)
    assert dE.mean() <= 0.5 and np.percentile(dE, 95) <= 1.0, (dE.mean(), np.percentile(dE, 95), dE.max())


@pytest.mark.parametrize("stack", ["1.38:99.6, 2.1:65.5", "2.3:60, 1.38:95, 2.3:60, 1.38:95"])
def test_stack_colour_matches_colour_science(variant_llvm_ad_rgb, stack):
    """A film stack (anti-reflection coating, dielectric mirror) in RGB against colour-science's
    ``multilayer_tmm`` spectrum converted to sRGB by colour-science."""
    from colour.phenomena import multilayer_tmm

    mi = variant_llvm_ad_rgb
    bsdf = mi.load_dict({"type": "thinfilm", "stack": stack, "substrate_ior": 1.52})
    ours = _sample_values(mi, bsdf, THETAS)
    layers = [[float(v) for v in layer.split(":")] for layer in stack.split(",")]
    lam = np.arange(360.0, 831.0, 1.0)
    R, _ = multilayer_tmm([1.0] + [n for n, _ in layers] + [1.52], [d for _, d in layers], lam, THETAS)
    ref = _srgb_under_d65(lam, R.reshape(len(lam), len(THETAS), 2).mean(axis=-1))
    dE = _delta_e(ours, ref)
    assert dE.mean() <= 0.5 and dE.max() <= 1.0, dE


def _tilted_plane_scene(mi, theta_deg, bsdf, res=16, spp=64):
    """A plane whose normal makes ``theta_deg`` with the view direction, filling the view, white sky."""
    t = np.radians(theta_deg)
    normal = [float(np.sin(t)), 0.0, float(np.cos(t))]
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 2, "hide_emitters": True},
        "sensor": {"type": "orthographic",
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0])
                   @ mi.ScalarTransform4f().scale([0.2, 0.2, 1]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "emitter": {"type": "constant"},
        "plane": {"type": "rectangle", "bsdf": bsdf,
                  "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=normal, up=[0, 1, 0])},
    })


def _plane_colours(mi, thetas, thicknesses, bsdf, spp):
    """Mean colour of the plane image for each (angle, thickness): (angles, thicknesses, 3)."""
    out = []
    for theta in thetas:
        scene = _tilted_plane_scene(mi, theta, bsdf, spp=spp)
        params = mi.traverse(scene)
        row = []
        for d in thicknesses:
            params["plane.bsdf.thickness"] = d
            params.update()
            row.append(np.array(mi.render(scene, seed=1), dtype=np.float64).reshape(-1, 3).mean(axis=0))
        out.append(row)
    return np.array(out)


def test_rgb_render_matches_mitsuba_spectral_render(variant_llvm_ad_spectral):
    """A render in llvm_ad_rgb against Mitsuba's own spectral render of the same scene, in ΔE*ab.

    Each plane image has one colour; its mean over 16x16 pixels at 1024 spp (1M wavelength
    samples) is Mitsuba's converged spectral → sRGB value for that direction.
    """
    bsdf = {"type": "thinfilm", "film_ior": 1.37, "substrate_ior": 1.6}
    thetas, thicknesses = [0.0, 40.0, 70.0], [150.0, 400.0, 650.0]
    spectral = _plane_colours(variant_llvm_ad_spectral, thetas, thicknesses, bsdf, spp=1024)
    with variant("llvm_ad_rgb") as mi:
        rgb = _plane_colours(mi, thetas, thicknesses, bsdf, spp=4)
    dE = _delta_e(rgb, spectral)
    assert dE.mean() <= 0.5 and dE.max() <= 1.0, dE


# --- normalisation and limits ---------------------------------------------------------


@pytest.mark.parametrize("mitsuba_variant", RGB_VARIANTS, indirect=True)
def test_unit_reflectance_is_white(mitsuba_variant):
    """A lossless film on a (nearly) perfect mirror reflects R = 1 at every wavelength: white."""
    mi = mitsuba_variant
    bsdf = mi.load_dict({"type": "thinfilm", "thickness": 530.0, "film_ior": 1.45,
                         "substrate_ior": 1.0, "substrate_k": 1e4})
    value = _sample_values(mi, bsdf, [0.0, 35.0, 75.0])
    np.testing.assert_allclose(value, 1.0, atol=1e-4)


@pytest.mark.parametrize("mitsuba_variant", RGB_VARIANTS, indirect=True)
@pytest.mark.parametrize("eta, k", [(1.6, 0.0), (0.2, 3.0)])
def test_thickness_zero_equals_conductor_in_rgb(mitsuba_variant, eta, k):
    """Without a film and with a non-dispersive substrate, R(λ) is flat: its colour is Mitsuba's conductor."""
    mi = mitsuba_variant
    film = mi.load_dict({"type": "thinfilm", "thickness": 0.0, "substrate_ior": eta, "substrate_k": k})
    conductor = mi.load_dict({"type": "conductor", "eta": eta, "k": k})
    thetas = [0.0, 30.0, 60.0, 85.0]
    np.testing.assert_allclose(_sample_values(mi, film, thetas), _sample_values(mi, conductor, thetas),
                               rtol=2e-5, atol=1e-7)


def test_colour_tables_match_colour_science(variant_llvm_ad_rgb):
    """The tables read from Mitsuba are the CIE 1931 2° CMFs, D65 and the sRGB matrix."""
    import colour

    from thinfilm.bsdf.rgb import mitsuba_colour_tables

    tables = mitsuba_colour_tables()
    lam = tables.wavelengths_nm
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    np.testing.assert_allclose(tables.cmf, cmfs[lam], atol=2e-6)
    visible = lam <= 780.0  # colour-science's D65 ends at 780 nm (extrapolated beyond), CIE's at 830
    d65 = colour.SDS_ILLUMINANTS["D65"][lam]
    np.testing.assert_allclose(tables.illuminant[visible] / tables.illuminant[lam == 560.0],
                               d65[visible] / d65[lam == 560.0], rtol=1e-5)
    np.testing.assert_allclose(tables.xyz_to_rgb, colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB, atol=1e-3)


def test_spectrum_film_index_refused_in_rgb(variant_llvm_ad_rgb):
    mi = variant_llvm_ad_rgb
    with pytest.raises(Exception, match="thinfilm: parameter 'film_ior': a spectrum needs a spectral variant"):
        mi.load_dict({"type": "thinfilm", "film_ior": {"type": "spectrum", "value": [(400.0, 1.4), (700.0, 1.38)]}})
    bsdf = mi.load_dict({"type": "thinfilm", "thickness": 0.0, "substrate_ior": 1.5,
                         "film_ior": {"type": "spectrum", "value": 1.4}})
    assert np.all(_sample_values(mi, bsdf, [0.0]) > 0)


# --- the free-standing sheet ------------------------------------------------------------------


@pytest.mark.parametrize("mitsuba_variant", RGB_VARIANTS, indirect=True)
def test_sheet_reflectance_and_transmittance_in_rgb_match_colour_science(mitsuba_variant):
    """A soap film in RGB: reflected and transmitted colours (the sample weights of each lobe,
    times its probability) against colour-science's ``thin_film_tmm`` R and T of the
    free-standing film, converted to linear sRGB under D65."""
    from colour.phenomena import thin_film_tmm

    mi = mitsuba_variant
    variant = mi.variant()
    thetas, thickness = [0.0, 35.0, 60.0], 420.0
    bsdf = mi.load_dict({"type": "thinfilm_sheet", "thickness": thickness, "film_ior": 1.33})
    lam = np.arange(360.0, 831.0, 1.0)
    R, T = thin_film_tmm([1.0, 1.33, 1.0], thickness, lam, np.asarray(thetas))
    ref_r = _srgb_under_d65(lam, R.mean(axis=-1))[:, 0]
    ref_t = _srgb_under_d65(lam, T.mean(axis=-1))[:, 0]
    for k, theta in enumerate(thetas):
        t = np.radians(theta)
        got = {}
        for lobe, s1 in (("r", 0.0), ("t", 0.999999)):
            if variant.startswith("scalar"):
                si = mi.SurfaceInteraction3f()
                si.wi = mi.Vector3f(np.sin(t), 0.0, np.cos(t))
                si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
                bs, w = bsdf.sample(mi.BSDFContext(), si, s1, mi.Point2f(0.5, 0.5))
                got[lobe] = np.array([w[0], w[1], w[2]]) * bs.pdf
            else:
                si = _interactions(mi, [theta])
                bs, w = bsdf.sample(mi.BSDFContext(), si, mi.Float(s1), mi.Point2f(0.5, 0.5))
                got[lobe] = np.array(w, dtype=np.float64).ravel() * np.array(bs.pdf)[0]
        assert _delta_e(got["r"], ref_r[k]) < 0.5, (theta, got["r"], ref_r[k])
        assert _delta_e(got["t"], ref_t[k]) < 0.5, (theta, got["t"], ref_t[k])
        np.testing.assert_allclose(got["r"] + got["t"], 1.0, atol=1e-5)   # lossless: R + T = 1
